"""Simulated machines that speak the vehicle protocols, for tests, SITL and bench runs.

- `ardupilot.SimArduPilot`: an ArduCopter/ArduPilot Rover stand-in without I/O (bytes and time
  in, frames out) flying the profile's kinematics;
- `vehicle.SimVehicle`: that simulator on a pty, a serial port or a pymavlink URL.
"""
