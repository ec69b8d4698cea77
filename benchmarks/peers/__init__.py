"""Peer implementations for ``benchmarks/bench_peers.py`` (no phc imports in the peers)."""
