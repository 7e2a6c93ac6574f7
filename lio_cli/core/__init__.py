"""Pure estimation: never imports lio_cli.io."""
