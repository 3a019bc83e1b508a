"""The docs' tests: the list of blocks not run here, at the end of a run, is written by tests/conftest.py (the
process that writes a pytest-xdist run's summary loads only the conftest of the paths it was given)."""
