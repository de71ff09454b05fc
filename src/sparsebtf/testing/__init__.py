"""Test tooling shipped with the package (the fuzz harness): no command-line import at module
level, nothing the library itself uses.

* :mod:`.corpus` — valid seed files for every registered format, made by our writers;
* :mod:`.mutation` — byte-level mutations and what each reader's user runs;
* :mod:`.semantic` — well-formed files that say impossible things, and their oracle;
* :mod:`.field_fuzz` — every field of coded files and a multi-τ model damaged in turn, the
  decode compared with the undamaged file's.
"""
