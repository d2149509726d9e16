"""``prp3mc init KIND FILE``: write a commented template that runs as it is (docs, *File formats*)."""

from importlib import resources
from pathlib import Path

from ..errors import OutputExistsError
from ..output import write_text
from . import command

KINDS = ("geometry", "budget", "study", "classes", "region")


def template(kind: str) -> str:
    """The commented template of ``kind`` (one of :data:`KINDS`)."""
    return resources.files("prp3mc").joinpath(f"data/templates/{kind}.toml").read_text(encoding="utf-8")


@command("init", "write a commented template file (geometry, budget, study, allocation classes or region)")
class InitCommand:
    @staticmethod
    def add_arguments(p):
        p.add_argument("kind", choices=KINDS, help="what to write")
        p.add_argument("file", type=Path, help="the file to write (a .toml name)")
        p.add_argument("--force", action="store_true", help="replace an existing file")

    @staticmethod
    def run(args) -> None:
        path = args.file
        if path.exists() and not args.force:
            raise OutputExistsError(f"{path} exists: choose another name or pass --force to replace it")
        if path.exists() and not path.is_file():
            raise OutputExistsError(f"{path} exists and is not a file")
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, template(args.kind))
        print(f"wrote {path} ({args.kind} template; the comments explain every key)")
