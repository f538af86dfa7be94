"""Turns a fitted model.json into a fixed-point C header (see docs/fixed-point.md)."""
