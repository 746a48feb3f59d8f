"""The house (docs/architecture.md): no module of ``wmr`` imports, directly or through others,
a module that imports it.  The layers contract itself is import-linter's (``lint-imports`` in
CI); circles inside one layer are what it cannot see, so they are checked here with grimp, the
graph library import-linter is built on."""

from __future__ import annotations

import grimp


def test_wmr_has_no_import_circles() -> None:
    graph = grimp.build_graph("wmr", exclude_type_checking_imports=True)
    circles = sorted({
        tuple(sorted((importer, imported)))
        for importer in graph.modules
        for imported in graph.find_modules_directly_imported_by(importer)
        if graph.chain_exists(importer=imported, imported=importer)
    })
    assert circles == [], f"import circles (each pair imports the other): {circles}"
