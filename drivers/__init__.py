"""Edges of foldcell: the wire (Zenoh, messages), session logs (MCAP), devices and their emulators."""
