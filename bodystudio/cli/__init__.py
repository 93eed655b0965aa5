"""Command-line interface: a thin typer layer over the API, one module per pipeline stage."""
