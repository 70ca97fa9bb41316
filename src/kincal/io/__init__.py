"""File formats: the only package that reads or writes files."""
