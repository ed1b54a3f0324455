"""Benchmarks and quality tables (`bakery bench …`): measure encodings against independent references."""
