"""Benchmarks behind ``aeromanip bench`` (and the scripts in ``benchmarks/``)."""
