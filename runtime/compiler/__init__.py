"""Compiler: a grafcet model turned into Python source, and the function blocks it calls."""
