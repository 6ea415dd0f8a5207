"""Frames, rotations and the WGS-84 Earth model, shared by every pipeline."""
