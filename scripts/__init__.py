"""Command-line entry points behind the `pih` console command."""
