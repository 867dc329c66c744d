"""Generalisation benchmark: random structures identified blind (issue 20, linear part)."""
