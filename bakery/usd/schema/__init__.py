"""Package data: bakery's codeless USD schema plugin (plugInfo.json, generatedSchema.usda). Generated from
``schemas/usd/schema.usda`` by ``python -m bakery.usd.sync_schemas``; do not edit by hand."""
