"""Pipeline stages: one module per stage, each a plain function ``stage(data, options) -> data``."""
