"""Deploying fieldkit on a robot: units, install, config file, and the preflight (doctor)."""
