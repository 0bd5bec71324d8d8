"""One agent: configuration, networks, advisor (App. A; any advisor as a plug-in with its
quality knobs: ``advisors``, ``advisor_quality``), selector (Eq. 1), noise, replay
buffer and the DDPG / ADDPG / TD3 / ATD3 learners (Alg. 2 / A3). Pure JAX functions.
"""
