"""fieldkit: design, simulate and field-deploy Buzz swarm behaviors."""

__version__ = "0.1.0"
