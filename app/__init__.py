"""cogmap application layer: the command-line interface and the viser web app."""
