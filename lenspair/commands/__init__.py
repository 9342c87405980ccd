"""Thin subcommands: each validates its arguments, calls one library entry point, returns a code."""
