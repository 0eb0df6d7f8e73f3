"""Services: orchestration of devices and the numerical pipeline."""
