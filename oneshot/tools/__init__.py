"""What the commands share: argument checks and one-line errors (cli), reading and writing files
safely (files), the machine (host), pictures (viz)."""
