"""What the commands share: argument checks and one-line errors (cli), the machine (host), pictures (viz)."""
