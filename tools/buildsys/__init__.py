"""build.py's code: one module per command (setup, compile, render, merge, testing, bench,
package), what they share (common) and the command line (cli). Standard library only."""
