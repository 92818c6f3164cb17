"""The node's parameters, declared once: their specs (names, defaults, ranges), the reference file generated from them, and the reader of parameter files."""
