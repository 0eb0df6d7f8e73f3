"""Domain models: the test setup, FRF data and solution records shared by every layer."""
