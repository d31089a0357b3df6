"""Projector random patterns and the projector-pattern structure-from-motion front end."""
