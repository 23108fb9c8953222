"""scenesim."""
