"""Validates workflow files against schemas/workflow-editor.json with an independent JSON Schema
(draft 2020-12) implementation, resolving each kind's schemas/<kind>.schema.json by $ref.
Usage: check_editor_schema.py SCHEMAS_DIR WORKFLOW.yaml... ; exit 1 on the first invalid file."""
import json
import pathlib
import sys

import jsonschema
import yaml

schemas = pathlib.Path(sys.argv[1])
editor = json.loads((schemas / "workflow-editor.json").read_text())
store = {p.name: json.loads(p.read_text()) for p in schemas.glob("*.schema.json")}
resolver = jsonschema.RefResolver(base_uri=schemas.resolve().as_uri() + "/", referrer=editor, store={
    (schemas.resolve().as_uri() + "/" + k): v for k, v in store.items()})
cls = jsonschema.validators.validator_for(editor)
cls.check_schema(editor)
for s in store.values():
    jsonschema.validators.validator_for(s).check_schema(s)
validator = cls(editor, resolver=resolver)
status = 0
for wf in sys.argv[2:]:
    doc = yaml.safe_load(pathlib.Path(wf).read_text())
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.path))
    for e in errors:
        print(f"{wf}: {'/'.join(map(str, e.path))}: {e.message}")
        status = 1
    if not errors:
        print(f"{wf}: valid")
sys.exit(status)
