"""`python -m clamgen ...`: the `clamgen` command run by a given interpreter (scripts call it with
`sys.executable`, so that they work whether or not the environment's `bin` is on PATH)."""

from clamgen.cli import main

if __name__ == "__main__":
    main()
