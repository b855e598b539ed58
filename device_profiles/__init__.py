"""Shipped device profiles: package data, installed as `fieldkit.device_profiles`."""
