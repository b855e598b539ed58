"""Flight recordings: what a robot saw and did, tick by tick, as rosbags (issue 16)."""
