"""The Clearpath Husky: its MCU's serial protocol and a GPS receiver, as one vehicle backend.

- `frame`: the MCU's frames (layout, CRC-16/CCITT-FALSE) and the resynchronising de-framer;
- `messages`: type codes, payload encoders and decoders, the inspector's `fields`;
- `gps`: `GpsCore`, NMEA (pynmea2) and UBX (pyubx2) bytes in, a fix out, without I/O;
- `controller`: `GotoController`, a differential base's go-to within speed and acceleration;
- `core`: `HuskyCore`, MCU and GPS as a `fieldkit.vehicle.core.VehicleCore`, without I/O;
- `link`: `Husky`, the core on the MCU's and the GPS's serial ports;
- `port`: `HuskyPort`, the node's `VehiclePort` over it.

docs/vehicles.md#clearpath-husky says what each does and what is verified.
"""
