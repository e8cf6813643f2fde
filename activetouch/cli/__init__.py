"""The `activetouch` command: argument parsing and dispatch (main.py), one module per sub-command
(commands/)."""
