"""``python -m geodem``: the same command line as the ``geodem`` script."""
from geodem.cli import app

if __name__ == "__main__":
    app(prog_name="geodem")
