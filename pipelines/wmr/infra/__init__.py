"""Infrastructure, below everything: typed errors, durable file writes, the one reader of input
files, output-path checks, where the non-Python sources live.  Imports nothing of wmr.
"""
