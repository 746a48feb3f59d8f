"""Adapters to the libraries and formats of the field, one subpackage each: ``fmi`` (fmpy),
``mcap`` (logs), ``rerun`` (views), ``ssp`` (packages for foreign masters), ``ocp``
(CasADi/IPOPT).
"""
