"""Batched MuJoCo simulation of the LEAP Hand task scenes."""
