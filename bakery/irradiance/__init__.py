"""Irradiance from SH-family encodings (seed 001, ZH3): evaluation, ZH3 solves, hallucination, deringing,
quantization and the exact reference. Pure numpy/scipy; arrays are per probe (P, ...) with 3 colour channels."""
