"""Trajectory evaluation: TUM I/O, association, Umeyama SE(3) alignment, ATE, RPE."""
