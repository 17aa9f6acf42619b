"""Shared neural-network blocks (torch-geometric idioms)."""
