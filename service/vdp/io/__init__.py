"""Adapters between CAN frames/files and the pure core."""
