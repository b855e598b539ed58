"""DJI Onboard SDK, OPEN protocol, as the Matrice 100 speaks it: our own implementation.

- `crc`: the header CRC16 and frame CRC32 (seed 0x3AA3, no final XOR);
- `crypto`: AES-256-ECB with the app key (the `cryptography` library's AES);
- `frame`: building and checking frames, `FrameReader` (the resynchronising de-framer);
- `messages`: command ids, return codes, and each value's layout (broadcast, version...);
- `core.DjiCore`: the host's side without I/O (activation, control authority, telemetry,
  tasks, movement control), a `fieldkit.vehicle.core.VehicleCore`;
- `link.DjiLink`: that core on a serial port, for the node.

The simulated M100 flight controller is `fieldkit.vehicle.sim.dji`. Facts and what is
unverified without an aircraft: docs/vehicles.md.
"""
