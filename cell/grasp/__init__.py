"""Grasp synthesis, the paper's steps 1-4 (and step 5 in cell.configuration)."""
