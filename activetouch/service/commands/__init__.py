"""The `activetouch` sub-commands, one module each; each exposes `register(subparsers)`."""
