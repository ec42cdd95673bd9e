"""A REST metrics query: each device's data rate, ICR and live angular error from the dashboard.

    python examples/rest_metrics.py http://127.0.0.1:8000
"""
import json
import sys
import urllib.request

base = sys.argv[1].rstrip("/")
with urllib.request.urlopen(f"{base}/api/devices", timeout=10) as response:
    devices = json.load(response)
for d in devices:
    icr = "-" if d["icr"] is None else f"{d['icr']:.3f}"
    rate = "-" if d["bytes_per_s"] is None else f"{d['bytes_per_s']:.0f} B/s"
    aad = "-" if d["aad_deg"] is None else f"{d['aad_deg']:.2f} deg"
    live = "-" if d["live_p99_deg"] is None else f"{d['live_p99_deg']:.2f} deg"
    print(f"{d['device']}: {rate}, ICR {icr}, angular error {aad} (exact frames), live p99 {live}")
