"""The aggregator's computation as it was before it was batched (commit 8cc7f27): messages taken
in one by one, frames and stats per device. Kept, unchanged but for its imports and the Zenoh
parts left out, as the plain reference that tests/test_aggregator_equality.py runs beside
``limbstream.services.aggregator`` on the same input; never imported by the package."""
