"""The MAVLink edge: links, message decoding, PX4 modes, the offboard sequence, tlogs."""
