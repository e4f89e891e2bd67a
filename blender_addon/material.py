"""Wire the albedo image into the object's materials, keeping the original.

On each material of the object (one is created if it has none) an Image
Texture node "Delight Albedo", fed by a UV Map node for the UV map the
texture was made on, goes into the Principled BSDF's Base Color. Whatever
fed Base Color before stays in the tree, unlinked, inside a Frame labelled
"Delight: original", so the user can compare and relink it. The names of our
nodes are stored in the material's ``"delight"`` custom property and the
nodes carry a ``"delight"`` tag: a re-run finds and reuses them instead of
stacking new ones, and does not frame our own node.
"""

from __future__ import annotations

import bpy

from .core.errors import DelightError

__all__ = ["IMAGE_NODE", "UV_NODE", "FRAME_LABEL", "wire_albedo", "target_materials", "check_editable"]

IMAGE_NODE = "Delight Albedo"
UV_NODE = "Delight UV"
FRAME_LABEL = "Delight: original"
TAG = "delight"


def target_materials(obj) -> list:
    """The distinct materials in the object's slots (may be empty)."""
    out = []
    for slot in obj.material_slots:
        if slot.material is not None and slot.material not in out:
            out.append(slot.material)
    return out


def check_editable(obj, mats=None):
    """Raise :class:`DelightError` if the object or its materials cannot be edited (linked data)."""
    mats = target_materials(obj) if mats is None else mats
    if obj.library is not None or obj.data.library is not None:
        raise DelightError(f"object {obj.name!r} is linked from a library and cannot get a material")
    for m in mats:
        if m.library is not None:
            raise DelightError(f"material {m.name!r} of {obj.name!r} is linked from a library; make it local first")


def _tagged(nt, role, name_hint):
    node = nt.nodes.get(name_hint) if name_hint else None
    if node is not None and node.get(TAG) == role:
        return node
    return next((n for n in nt.nodes if n.get(TAG) == role), None)


def _output_node(nt):
    outs = [n for n in nt.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
    return next((n for n in outs if n.is_active_output), outs[0] if outs else None)


def _find_principled(nt, hint):
    node = nt.nodes.get(hint) if hint else None
    if node is not None and node.bl_idname == "ShaderNodeBsdfPrincipled":
        return node
    out = _output_node(nt)
    if out is not None:
        for link in out.inputs["Surface"].links:
            if link.from_node.bl_idname == "ShaderNodeBsdfPrincipled":
                return link.from_node
    return next((n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)


def _upstream_only(nt, socket, keep):
    """Nodes feeding ``socket`` that feed nothing outside that subtree (and are not ``keep``)."""
    found, todo = [], [link.from_node for link in socket.links]
    while todo:
        n = todo.pop()
        if n in found or n in keep:
            continue
        found.append(n)
        todo.extend(link.from_node for inp in n.inputs for link in inp.links)
    # Drop nodes that also feed something else: framing must not tear them away.
    changed = True
    while changed:
        changed = False
        for n in list(found):
            for out in n.outputs:
                for link in out.links:
                    if link.to_node not in found and link.to_socket != socket:
                        found.remove(n)
                        changed = True
                        break
                if n not in found:
                    break
    return found


def _frame_original(nt, socket, state, keep):
    """Unlink what feeds ``socket``; put its own nodes in the "original" frame."""
    nodes = _upstream_only(nt, socket, keep)
    for link in list(socket.links):
        nt.links.remove(link)
    if not nodes:
        return
    frame = _tagged(nt, "frame", state.get("frame"))
    if frame is None:
        frame = nt.nodes.new("NodeFrame")
        frame[TAG] = "frame"
        frame.label = FRAME_LABEL
        frame.name = "Delight Original"
    for n in nodes:
        if n.bl_idname != "NodeFrame" and n.parent is None:
            n.parent = frame
    state["frame"] = frame.name


def _wire(mat, image, uv_map):
    if mat.node_tree is None:  # an old material that never used nodes
        mat.use_nodes = True
    nt = mat.node_tree
    state = dict(mat.get(TAG, {}))
    principled = _find_principled(nt, state.get("principled"))
    if principled is None:
        principled = nt.nodes.new("ShaderNodeBsdfPrincipled")
        out = _output_node(nt) or nt.nodes.new("ShaderNodeOutputMaterial")
        principled.location = (out.location.x - 300, out.location.y)
        _frame_original(nt, out.inputs["Surface"], state, keep={out, principled})
        nt.links.new(principled.outputs["BSDF"], out.inputs["Surface"])
    state["principled"] = principled.name

    tex = _tagged(nt, "albedo", state.get("image_node"))
    uvn = _tagged(nt, "uv", state.get("uv_node"))
    base = principled.inputs["Base Color"]
    if any(link.from_node != tex for link in base.links):
        _frame_original(nt, base, state, keep={principled, tex, uvn})
    x, y = principled.location.x, principled.location.y
    if tex is None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex[TAG] = "albedo"
        tex.name = tex.label = IMAGE_NODE
        tex.location = (x - 420, y + 420)
    if uvn is None:
        uvn = nt.nodes.new("ShaderNodeUVMap")
        uvn[TAG] = "uv"
        uvn.name = uvn.label = UV_NODE
        uvn.location = (tex.location.x - 220, tex.location.y - 120)
    tex.image = image
    tex.interpolation = "Linear"
    uvn.uv_map = uv_map or ""
    nt.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    if not any(link.from_node == tex for link in base.links):
        nt.links.new(tex.outputs["Color"], base)
    state.update(image_node=tex.name, uv_node=uvn.name)
    mat[TAG] = state
    return mat


def wire_albedo(obj, image, uv_map: str | None = None) -> list:
    """Put ``image`` on Base Color of every material of ``obj``; return the materials.

    Parameters
    ----------
    obj : bpy.types.Object
        A mesh object.
    image : bpy.types.Image
    uv_map : str, optional
        The UV map the texture is on (default: the mesh's default UV map).

    Raises
    ------
    DelightError
        The object or one of its materials is linked from a library. Nothing
        is changed then.
    """
    mats = target_materials(obj)
    check_editable(obj, mats)
    if not mats:
        mat = bpy.data.materials.new(f"{obj.name}_material")
        if not obj.material_slots:
            obj.data.materials.append(mat)
        else:
            for slot in obj.material_slots:
                slot.material = mat
        mats = [mat]
    return [_wire(m, image, uv_map) for m in mats]
