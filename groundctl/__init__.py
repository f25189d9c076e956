"""groundctl: a ground station for formation drone light shows."""

__version__ = "0.1.0"
