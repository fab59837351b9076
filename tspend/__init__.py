"""tspend: on-line T-S fuzzy modeling and robust adaptive control testbed."""
__version__ = "0.1.0"
