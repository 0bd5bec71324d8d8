"""brax's SAC and PPO trained as baseline agent types (``--agent brax-SAC|brax-PPO``):
the options (``request``), the episode budget (``episodes``), one seed (``trainer``) and
the run directory (``run``). docs/baselines.md, "brax SAC and PPO"."""
