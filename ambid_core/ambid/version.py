"""The version of the ambid distribution (ambid_core/pyproject.toml says the same)."""

__version__ = "0.2.0"
