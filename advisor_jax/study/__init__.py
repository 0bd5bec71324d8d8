"""Studies: a TOML file of agent types × static settings × grid × seeds (``spec``), planned
into pieces that fit a device (``plan``, ``throughput``) and run resumably (``sweep``)."""
