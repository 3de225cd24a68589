"""Viewers of the fusion center: the live web view and Foxglove-compatible ``/viz`` channels."""
