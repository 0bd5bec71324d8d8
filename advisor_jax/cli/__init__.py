"""The ``advisor-jax`` console script (``main``) and its subcommands."""
