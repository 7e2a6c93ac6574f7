"""``python -m lio_cli ...`` runs the ``lio`` command (handy inside a checkout without installing)."""

from .cli.launch import entry

entry()
