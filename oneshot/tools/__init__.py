"""What the commands share: argument checks and one-line errors (cli), checks of plain values (checks),
reading and writing files safely (files), the machine (host), pictures (viz)."""
