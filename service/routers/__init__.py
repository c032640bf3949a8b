"""The API's routers, one per resource: shapes, models, health."""
