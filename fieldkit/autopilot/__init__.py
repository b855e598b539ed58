"""Left over from the rename to `fieldkit.vehicle`: the `vehicle-sim` command line, and one
re-export (`vehicle_sim`) kept for `fieldkit.sitl` until it imports `fieldkit.vehicle`."""
