"""The compositional NF-MP core (paper §II-B): configuration, model, training, inference.

``configuration_cnfmp`` holds the documented config dataclass, ``modeling_cnfmp`` the torch
model, ``training_cnfmp`` its training loop, ``inference`` the simplex-weight search;
``models`` the model types (this one and the baselines) and the model-directory format,
``training`` the seeded training run of any type, ``api`` the entry points the Rust bridge
calls.
"""
