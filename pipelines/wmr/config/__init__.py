"""Configuration: scenario files (TOML) validated into run specs, a run written back as a scenario,
run names.
"""
