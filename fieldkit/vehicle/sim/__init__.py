"""Simulated machines that speak the vehicle protocols, for tests, SITL and bench runs.

- `ardupilot.SimArduPilot`: an ArduCopter/ArduPilot Rover stand-in without I/O (bytes and time
  in, frames out) flying the profile's kinematics;
- `vehicle.SimVehicle`: that simulator on a pty, a serial port or a pymavlink URL.
- `husky.SimHusky`: a Clearpath Husky's MCU (acks, data, its command watchdog) and GPS
  receiver (NMEA or UBX) without I/O, driving the shared differential-drive model;
- `husky_pty.SimHuskyPorts`: that Husky on two lines, the MCU's and the GPS's.
"""
