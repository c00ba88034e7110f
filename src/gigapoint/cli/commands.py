"""Imports every command module so each registers on the app (``gigapoint`` itself imports only
the one a command line names: app.py's ``register_commands``)."""

from .app import register_commands

register_commands()
