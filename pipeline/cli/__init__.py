"""The `mvpd` command: parses, delegates, prints. Nothing imports this package."""
