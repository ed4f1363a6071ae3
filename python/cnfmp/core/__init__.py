"""The compositional NF-MP core (paper §II-B): configuration, model, training, inference.

``configuration_cnfmp`` holds the documented config dataclass, ``modeling_cnfmp`` the torch
model and the model-directory format, ``training`` the seeded training run, ``inference``
the simplex-weight search, ``api`` the entry points the Rust bridge calls.
"""
