"""Ready-made cases: one module per case (its model or scene recipe, its result step, its
pictures), registered with the workflow registries (:data:`geodem.registry.BUILTINS`)."""
