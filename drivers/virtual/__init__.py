"""A virtual Protocol 2.0 servo bus on a pseudo-terminal, backed by a plant."""
