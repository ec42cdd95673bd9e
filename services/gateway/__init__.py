"""Gateways: devices that cannot speak Zenoh, bridged in."""
