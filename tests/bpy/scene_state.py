"""A snapshot of what a Delight run may change in a scene, to check that a failed or cancelled run changed nothing."""

from __future__ import annotations

import bpy


def _tree(nt):
    if nt is None:
        return None
    nodes = sorted(
        (n.name, n.bl_idname, n.parent.name if n.parent else None, getattr(getattr(n, "image", None), "name", None))
        for n in nt.nodes
    )
    links = sorted(
        (l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier) for l in nt.links
    )
    return nodes, links


def scene_state() -> dict:
    """Datablock names and every material's node tree, links and custom properties."""
    d = bpy.data
    state = {
        k: sorted(x.name for x in getattr(d, k))
        for k in ("images", "objects", "meshes", "materials", "cameras", "collections", "node_groups")
    }
    state["trees"] = {m.name: _tree(m.node_tree) for m in d.materials}
    state["material_props"] = {m.name: sorted(m.keys()) for m in d.materials}
    state["slots"] = {o.name: [s.material.name if s.material else None for s in o.material_slots] for o in d.objects}
    state["packed"] = sorted(i.name for i in d.images if i.packed_file is not None)
    state["is_dirty_images"] = sorted(i.name for i in d.images if i.is_dirty)
    return state


def files_under(folder) -> list:
    """Every path under ``folder`` (relative), hidden ones included."""
    import os

    out = []
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            out.append(os.path.relpath(os.path.join(root, name), folder))
    return sorted(out)
