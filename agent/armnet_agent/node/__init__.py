"""The node agent: one process per robot host running the jobs bound to its cells."""
