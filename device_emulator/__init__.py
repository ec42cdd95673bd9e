"""Emulated wearable IMUs that run the C fastSW kernel and publish segment points over Zenoh."""
