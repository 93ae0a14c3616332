"""Placeholder: filled in by the brazilian lab test."""
