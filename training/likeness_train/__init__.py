"""Likeness training: the paper's ModelNet + TrackNet, trained self-supervised on synthetic people."""
