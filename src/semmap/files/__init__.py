"""File helpers every layer may use: atomic writes (`atomic`) and the checks for reading handed-over files (`safe`)."""
