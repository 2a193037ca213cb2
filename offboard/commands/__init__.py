"""Sub-commands of `offboard`; each module has ``register(subparsers)``."""
