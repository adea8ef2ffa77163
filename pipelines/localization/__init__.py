"""Coarse-to-fine visual localization (GL + LL) and its state machine."""
