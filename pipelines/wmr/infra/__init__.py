"""Infrastructure, below everything: typed errors, durable file writes, output-path checks, where
the non-Python sources live.  Imports nothing of wmr.
"""
