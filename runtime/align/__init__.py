"""Alignment of key frames (paper: cross-frame and multi-frame alignment)."""
