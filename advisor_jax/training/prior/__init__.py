"""A baseline's prior-knowledge phases (LfD, MCP+MF; docs/baselines.md) as a program built
beside the RL core: ``phases`` (the hook and its gate), ``lfd`` and ``mcp`` (the phases),
``trainer`` (the program that scans them with the core's pieces)."""
