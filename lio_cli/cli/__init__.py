"""The typer CLI. The only place that prints with rich, exits, or draws progress bars."""
