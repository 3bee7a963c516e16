"""Reading the files of the command-line contract (spec/formats.md)."""
