"""Rerun: replay of run logs, the live view of a run, the blueprint for raw logs.
"""
