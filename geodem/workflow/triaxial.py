"""Placeholder: filled in by the triaxial lab test."""
