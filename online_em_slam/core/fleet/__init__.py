"""Fleet mode: R robots, each with its own particle filter, and one map (docs/METHOD.md, "Fleet mode")."""
