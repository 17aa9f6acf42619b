"""Batched position-based particle engine and renderer (no torch.nn in here).

Every function works on tensors of shape [B, N, 3] (B scenes advanced together), on CPU or GPU.
"""
