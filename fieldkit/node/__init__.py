"""The field node: the script on a real robot, against its autopilot and radio."""
