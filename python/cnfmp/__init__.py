"""cnfmp: the Python half of Compositional Neural Field Movement Primitives.

The Rust orchestrator (`cnfmp` binary) embeds this package through `segmenter-bridge`; every
function the bridge calls is a small documented entry point. The package is also usable on its
own (tests, notebooks). Subpackages: `runtime` (process set-up: threads, offline flags, GL),
`doctor` (environment report); later `segmenter`, `core`, `sim`, `data`.
"""

__version__ = "0.1.0"
