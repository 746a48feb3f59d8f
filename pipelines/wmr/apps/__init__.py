"""Applications, one per command: run, batch, optimal, benchmark, tune, figures, the sensing study.
"""
