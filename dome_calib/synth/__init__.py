"""Synthetic dome captures with ground truth: layout, tent, rendering, capture writer."""
