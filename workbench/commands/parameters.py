"""``workbench parameters``: every scenario.* and instrument.* parameter a study may set."""
from __future__ import annotations

import dataclasses
import typing

from workbench.config import parameter_paths


def add_parser(sub) -> None:
    """The ``parameters`` subcommand."""
    sub.add_parser("parameters", help="list every scenario.*, instrument.* and design.* parameter with its default "
                                      "and doc")


def parameters_command(args) -> int:
    from workbench.design.inputs import DesignInput
    from workbench.scenario import Instrument, Scenario

    for root, cls in (("scenario", Scenario), ("instrument", Instrument), ("design", DesignInput)):
        for path in parameter_paths(cls):
            obj, owner = cls(), cls
            parts = path.split(".")
            for name in parts[:-1]:
                # an array of tables ("camera[]"): its first default item shows the item's defaults
                obj = getattr(obj, name[:-2])[0] if name.endswith("[]") else getattr(obj, name)
                owner = type(obj)
            f = {x.name: x for x in dataclasses.fields(owner)}[parts[-1]]
            hint = typing.get_type_hints(owner)[parts[-1]]
            meta = dict(f.metadata)
            extra = [f"one of {', '.join(map(str, meta['choices']))}" if "choices" in meta else "",
                     f">= {meta['min']}" if meta.get("min") is not None and "choices" not in meta else "",
                     f"<= {meta['max']}" if meta.get("max") is not None and "choices" not in meta else ""]
            bounds = "; ".join(e for e in extra if e)
            print(f"{root}.{path} = {getattr(obj, parts[-1])!r}  [{getattr(hint, '__name__', str(hint))}"
                  f"{'; ' + bounds if bounds else ''}]  {meta.get('doc', '')}")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("parameters", None): parameters_command}
