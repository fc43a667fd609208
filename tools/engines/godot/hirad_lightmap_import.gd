@tool
extends EditorScript
## hirad lightmaps -> a Godot 4 LightmapGI, without a Godot bake.
##
## Run it from the Script Editor (File > Run, Ctrl+Shift+X) with the scene that holds the
## imported meshes open. It reads hirad's OUT/lightmaps/manifest.json (version 2) and the page
## EXRs it lists, and builds:
##   * a Texture2DArray with one slice per hirad page (linear half float, RGBA),
##   * a LightmapGIData whose users are the scene's MeshInstance3D nodes, each with its page
##     (slice_index) and its rectangle on that page (uv_scale, a Rect2),
##   * a LightmapGI node (named LIGHTMAP_NODE_NAME) under the scene root holding that data.
## Both resources are saved under OUTPUT_DIR. Set the constants below first.
##
## What the meshes must bring: their lightmap UVs as Godot's UV2. hirad's GLB
## (tools/hirad/outputs/gltf.py, OUT/<name>.glb) stores each mesh's own lightmap set st1 as
## glTF TEXCOORD_1, which Godot's glTF importer reads into Mesh.ARRAY_TEX_UV2. In the GLB's
## Import dock set "Meshes > Light Baking" to "Static" (NOT "Static Lightmaps": that one
## unwraps a new UV2 of Godot's own and the rectangles below no longer fit it). This script
## refuses a matched mesh without UV2 and sets gi_mode = GI_MODE_STATIC on every mesh it binds.
##
## The manifest (written by tools/hirad/outputs/lightmaps.py), what this script reads of it:
##   uvOrigin            starts with "bottom-left": st1 and scaleOffset follow USD (v up)
##   engines.godot.flipV true: Godot's UVs have their origin at the top-left
##   pages[k]            file (relative to the manifest's folder), width, height
##   instances[i]        prim (the ORIGINAL USD prim path), page, scaleOffset [sx, sy, ox, oy]
##                       in Unity's order: page_uv = st1 * (sx, sy) + (ox, oy), USD convention
## The page texels are incident radiance H/pi in W/(m^2 sr): the light a white Lambertian
## surface reflects. Godot multiplies a lightmap texel by the albedo, as it does its direct
## light's E/pi, so the values go in unscaled (pick the camera exposure for W/(m^2 sr)).
##
## The rectangle (why uv_scale is not scaleOffset):
##   Godot's shader (scene_forward_clustered.glsl) reads the lightmap at
##       page_uv_godot = UV2 * uv_scale.size + uv_scale.position
##   in the slice's own UVs, origin top-left (image row 0 at v = 0).
##   hirad's page UV of a corner with st1 = (u, v) is P = (sx u + ox, sy v + oy) with the
##   origin bottom-left; its image row is (1 - P.y) * height (row 0 = top = P.y = 1).
##   The same corner's UV2 in Godot is (u, t) with t = 1 - v (glTF's flip, kept by Godot).
##   So page_uv_godot = (P.x, 1 - P.y)
##       = (sx u + ox, 1 - sy (1 - t) - oy)
##       = (u, t) * (sx, sy) + (ox, 1 - sy - oy),
##   i.e. uv_scale = Rect2(position = (ox, 1 - sy - oy), size = (sx, sy)).
##   A Texture2DArray needs one size for every slice: a page smaller than the largest
##   (W x H) is copied into the top-left corner of its slice unscaled (no resampling), so in
##   slice UVs its coordinates shrink by (w / W, h / H):
##       uv_scale = Rect2(ox * w / W, (1 - sy - oy) * h / H, sx * w / W, sy * h / H).
##   tests/python/outputs/test_engine_scripts.py re-derives this and checks it lands every
##   corner on the texel hirad's own page UVs name.
##
## Which node is which prim (first rule with exactly one match wins; two matches are an error):
##   1. the node's metadata "extras" has hirad_path == prim (Godot >= 4.3 imports glTF node
##      extras as metadata; hirad's GLB puts the prim path there);
##   2. the node's name is the prim path with the characters Godot removes from node names
##      (. : @ / " % and, in some versions, replaced by _) dropped: hirad's GLB names each
##      node by its prim path, so "/World/box" arrives as "Worldbox" (or "_World_box");
##   3. the node's own path from the scene root ends with the prim's path components (a
##      hierarchy that mirrors the USD prims, e.g. .../World/box).
## Not done: light probes for dynamic objects (LightmapGIData's probe data); directional
## (SH) lightmaps; MultiMesh sub-instances (every user gets sub_instance -1).
##
## Godot API used (4.0 to 4.4, checked against the class reference and lightmap_gi.cpp):
## LightmapGIData.add_user(path, uv_scale: Rect2, slice_index, sub_instance), light_texture
## (4.0-4.2) or lightmap_textures (4.3+), LightmapGI.light_data,
## Texture2DArray.create_from_images. Not run here: no Godot 4 on this machine.

## Where hirad's manifest is (res:// or an absolute path); the pages are read beside it.
const MANIFEST_PATH := "res://hirad/lightmaps/manifest.json"
## Where the Texture2DArray and the LightmapGIData are saved (inside the project).
const OUTPUT_DIR := "res://hirad/imported"
## Name of the LightmapGI node under the edited scene's root (reused when it exists).
const LIGHTMAP_NODE_NAME := "HiradLightmapGI"
## Manifest version this script was written against.
const MANIFEST_VERSION := 2

var _errors: PackedStringArray = []
var _warnings: PackedStringArray = []


func _run() -> void:
	_errors.clear()
	_warnings.clear()
	var root: Node = get_scene()
	if root == null:
		push_error("hirad: open the scene that holds the imported meshes first")
		return
	var manifest := _read_manifest(MANIFEST_PATH)
	if _report():
		return
	var pages := _read_pages(manifest, MANIFEST_PATH.get_base_dir())
	if _report():
		return
	var users := _match_instances(manifest, root, pages)
	if _report():
		return
	var tex := _page_array(pages)
	if _report():
		return
	_build(root, tex, users)
	_report()


# ---------------------------------------------------------------------------------------
# The manifest: every key read goes through _req (must exist, of that kind).


func _fail(message: String) -> void:
	_errors.append("%s: %s" % [MANIFEST_PATH, message])


func _is_kind(v, kind: String) -> bool:
	var t := typeof(v)
	var ok := false
	match kind:
		"string":
			ok = t == TYPE_STRING
		"bool":
			ok = t == TYPE_BOOL
		"number":
			ok = t == TYPE_FLOAT or t == TYPE_INT
		"int":
			ok = (t == TYPE_FLOAT and v == floor(v)) or t == TYPE_INT
		"array":
			ok = t == TYPE_ARRAY
		"dict":
			ok = t == TYPE_DICTIONARY
		"number4":
			ok = t == TYPE_ARRAY and v.size() == 4
			if ok:
				for x in v:
					ok = ok and (typeof(x) == TYPE_FLOAT or typeof(x) == TYPE_INT)
	return ok


## The value of `key` in `d` (a dictionary found at `where`), which must be of `kind`.
func _req(d: Dictionary, key: String, kind: String, where: String):
	if not d.has(key):
		_fail("%s has no \"%s\"" % [where, key])
		return null
	var v = d[key]
	if not _is_kind(v, kind):
		_fail("%s.%s is %s, expected %s" % [where, key, type_string(typeof(v)), kind])
		return null
	return v


func _read_manifest(path: String) -> Dictionary:
	if not FileAccess.file_exists(path):
		_fail("no such file (set MANIFEST_PATH in this script)")
		return {}
	var text := FileAccess.get_file_as_string(path)
	var json := JSON.new()
	if json.parse(text) != OK:
		_fail("line %d: %s" % [json.get_error_line(), json.get_error_message()])
		return {}
	if typeof(json.data) != TYPE_DICTIONARY:
		_fail("the top level is not a JSON object")
		return {}
	var manifest: Dictionary = json.data
	var version = _req(manifest, "version", "int", "manifest")
	if version != null and int(version) != MANIFEST_VERSION:
		_fail("version %d; this script reads version %d" % [int(version), MANIFEST_VERSION])
	var origin = _req(manifest, "uvOrigin", "string", "manifest")
	if origin != null and not String(origin).begins_with("bottom-left"):
		_fail("uvOrigin is \"%s\"; the rectangle formula here assumes bottom-left (USD)" % origin)
	var engines = _req(manifest, "engines", "dict", "manifest")
	if engines != null:
		var godot = _req(engines, "godot", "dict", "manifest.engines")
		if godot != null:
			var flip = _req(godot, "flipV", "bool", "manifest.engines.godot")
			if flip != null and flip != true:
				_fail("engines.godot.flipV is false; this script applies Godot's V flip itself")
	_req(manifest, "pages", "array", "manifest")
	_req(manifest, "instances", "array", "manifest")
	return manifest


# ---------------------------------------------------------------------------------------
# Pages: the EXRs, each checked against the size the manifest states.


func _read_pages(manifest: Dictionary, base: String) -> Array:
	var pages := []
	var list: Array = manifest["pages"]
	for k in list.size():
		var where := "pages[%d]" % k
		if typeof(list[k]) != TYPE_DICTIONARY:
			_fail("%s is not an object" % where)
			continue
		var page: Dictionary = list[k]
		var file = _req(page, "file", "string", where)
		var width = _req(page, "width", "int", where)
		var height = _req(page, "height", "int", where)
		if file == null or width == null or height == null:
			continue
		var path := base.path_join(file)
		var image := Image.load_from_file(path)
		if image == null or image.is_empty():
			_fail("%s: cannot read the page image %s" % [where, path])
			continue
		if image.get_width() != int(width) or image.get_height() != int(height):
			_fail("%s: %s is %dx%d, the manifest says %dx%d" % [where, path, image.get_width(),
					image.get_height(), int(width), int(height)])
			continue
		image.convert(Image.FORMAT_RGBAH)  # one format for every slice; linear, no sRGB
		pages.append(image)
	return pages


## One Texture2DArray slice per page, all of the largest page's size; a smaller page sits
## unscaled in its slice's top-left corner (see the rectangle derivation at the top).
func _page_array(pages: Array) -> Texture2DArray:
	var size := Vector2i(1, 1)
	for image in pages:
		size = Vector2i(maxi(size.x, image.get_width()), maxi(size.y, image.get_height()))
	var slices: Array[Image] = []
	for image in pages:
		if image.get_size() == size:
			slices.append(image)
		else:
			var slice := Image.create(size.x, size.y, false, Image.FORMAT_RGBAH)
			slice.blit_rect(image, Rect2i(Vector2i.ZERO, image.get_size()), Vector2i.ZERO)
			slices.append(slice)
	var tex := Texture2DArray.new()
	if tex.create_from_images(slices) != OK:
		_fail("Godot could not make a Texture2DArray of %d pages of %dx%d"
				% [slices.size(), size.x, size.y])
		return null
	return tex


## hirad's Unity-order scaleOffset (USD UVs, origin bottom-left) -> Godot's uv_scale for a
## page of page_size placed at the top-left of a slice of slice_size.
static func godot_uv_scale(so: Array, page_size: Vector2i, slice_size: Vector2i) -> Rect2:
	var kx := float(page_size.x) / float(slice_size.x)
	var ky := float(page_size.y) / float(slice_size.y)
	var sx := float(so[0])
	var sy := float(so[1])
	var ox := float(so[2])
	var oy := float(so[3])
	return Rect2(ox * kx, (1.0 - sy - oy) * ky, sx * kx, sy * ky)


# ---------------------------------------------------------------------------------------
# Instances -> nodes


## Node names drop these characters (String.validate_node_name); newer versions may turn
## them into "_", so "_" is dropped too before comparing.
static func _canonical(name: String) -> String:
	var out := name
	for c in [".", ":", "@", "/", "\"", "%", "_"]:
		out = out.replace(c, "")
	return out


func _mesh_nodes(node: Node, out: Array) -> void:
	if node is MeshInstance3D:
		out.append(node)
	for child in node.get_children():
		_mesh_nodes(child, out)


func _find_node(prim: String, candidates: Array, root: Node) -> Array:
	var by_extras := []
	var by_name := []
	var by_path := []
	var want := _canonical(prim)
	var parts := []
	for p in prim.split("/", false):
		parts.append(_canonical(p))
	for node in candidates:
		var extras = node.get_meta("extras", null)
		if typeof(extras) == TYPE_DICTIONARY and extras.get("hirad_path", "") == prim:
			by_extras.append(node)
		if _canonical(String(node.name)) == want:
			by_name.append(node)
		var names := []
		var n: Node = node
		while n != null and n != root:
			names.push_front(_canonical(String(n.name)))
			n = n.get_parent()
		var tail := names.slice(names.size() - parts.size()) if names.size() >= parts.size() else []
		if parts.size() > 0 and tail == parts:
			by_path.append(node)
	for found in [by_extras, by_name, by_path]:
		if found.size() > 0:
			return found
	return []


func _has_uv2(mesh: Mesh) -> bool:
	if mesh == null or mesh.get_surface_count() == 0:
		return false
	for s in mesh.get_surface_count():
		var arrays := mesh.surface_get_arrays(s)
		if arrays.size() <= Mesh.ARRAY_TEX_UV2 or arrays[Mesh.ARRAY_TEX_UV2] == null:
			return false
	return true


func _match_instances(manifest: Dictionary, root: Node, pages: Array) -> Array:
	var candidates := []
	_mesh_nodes(root, candidates)
	var size := Vector2i(1, 1)
	for image in pages:
		size = Vector2i(maxi(size.x, image.get_width()), maxi(size.y, image.get_height()))
	var users := []
	var list: Array = manifest["instances"]
	var missing := PackedStringArray()
	var taken := {}  # node -> the prim it was matched to
	for i in list.size():
		var where := "instances[%d]" % i
		if typeof(list[i]) != TYPE_DICTIONARY:
			_fail("%s is not an object" % where)
			continue
		var inst: Dictionary = list[i]
		var prim = _req(inst, "prim", "string", where)
		var page = _req(inst, "page", "int", where)
		var so = _req(inst, "scaleOffset", "number4", where)
		if prim == null or page == null or so == null:
			continue
		if int(page) < 0 or int(page) >= pages.size():
			_fail("%s (%s): page %d, the manifest has %d pages" % [where, prim, int(page), pages.size()])
			continue
		var found := _find_node(prim, candidates, root)
		if found.is_empty():
			missing.append(prim)
			continue
		if found.size() > 1:
			var names := PackedStringArray()
			for n in found:
				names.append(String(root.get_path_to(n)))
			_fail("%s: %s matches %d nodes (%s); rename or remove all but one"
					% [where, prim, found.size(), ", ".join(names)])
			continue
		var node: MeshInstance3D = found[0]
		if taken.has(node):
			_fail("%s: %s and %s both match the node %s"
					% [where, taken[node], prim, root.get_path_to(node)])
			continue
		taken[node] = prim
		if not _has_uv2(node.mesh):
			_errors.append(("%s: %s (%s) has no UV2; import it with hirad's GLB (TEXCOORD_1) and"
					+ " Light Baking = Static") % [root.get_path_to(node), prim, where])
			continue
		var image: Image = pages[int(page)]
		users.append({"node": node, "slice": int(page),
				"rect": godot_uv_scale(so, image.get_size(), size)})
	if not missing.is_empty():
		_warnings.append("%d manifest instances have no node in this scene and get no lightmap: %s" % [
				missing.size(), ", ".join(missing.slice(0, 8)) + (" ..." if missing.size() > 8 else "")])
	if users.is_empty() and _errors.is_empty():
		_fail("no instance of the manifest matched a MeshInstance3D of the open scene")
	return users


# ---------------------------------------------------------------------------------------
# Resources and the node


## Saves through a temporary name and a rename, so a failure leaves the old file.
func _save(resource: Resource, path: String) -> Resource:
	var tmp := path.get_basename() + ".partial." + path.get_extension()
	var err := ResourceSaver.save(resource, tmp)
	if err != OK:
		_errors.append("%s: cannot be written (%s)" % [tmp, error_string(err)])
		return null
	err = DirAccess.rename_absolute(ProjectSettings.globalize_path(tmp),
			ProjectSettings.globalize_path(path))
	if err != OK:
		_errors.append("%s: cannot be renamed to %s (%s)" % [tmp, path, error_string(err)])
		return null
	return ResourceLoader.load(path, "", ResourceLoader.CACHE_MODE_REPLACE)


func _build(root: Node, tex: Texture2DArray, users: Array) -> void:
	DirAccess.make_dir_recursive_absolute(ProjectSettings.globalize_path(OUTPUT_DIR))
	var saved_tex = _save(tex, OUTPUT_DIR.path_join("hirad_lightmaps.res"))
	if saved_tex == null:
		return
	var existing := root.get_node_or_null(NodePath(LIGHTMAP_NODE_NAME))
	if existing != null and not existing is LightmapGI:
		_errors.append("%s: the scene has a node of that name that is not a LightmapGI"
				% LIGHTMAP_NODE_NAME)
		return
	var lm: LightmapGI = existing
	if lm == null:
		lm = LightmapGI.new()
		lm.name = LIGHTMAP_NODE_NAME
		root.add_child(lm)
		lm.owner = root
	var data := LightmapGIData.new()
	if data.has_method("set_lightmap_textures"):  # Godot 4.3+
		var textures: Array[TextureLayered] = [saved_tex]
		data.call("set_lightmap_textures", textures)
	else:  # Godot 4.0 - 4.2
		data.set("light_texture", saved_tex)
	data.set_uses_spherical_harmonics(false)
	for u in users:
		var node: MeshInstance3D = u["node"]
		if node.gi_mode != GeometryInstance3D.GI_MODE_STATIC:
			node.gi_mode = GeometryInstance3D.GI_MODE_STATIC
		data.add_user(lm.get_path_to(node), u["rect"], u["slice"], -1)
	var saved_data = _save(data, OUTPUT_DIR.path_join("hirad_lightmap_data.res"))
	if saved_data == null:
		return
	lm.directional = false
	lm.light_data = saved_data
	get_editor_interface().get_resource_filesystem().scan()
	print("hirad: %d meshes lightmapped from %d pages (%s); save the scene to keep %s" % [
			users.size(), saved_tex.get_layers(), MANIFEST_PATH, LIGHTMAP_NODE_NAME])


func _report() -> bool:
	for w in _warnings:
		push_warning("hirad: " + w)
	_warnings.clear()
	for e in _errors:
		push_error("hirad: " + e)
	return not _errors.is_empty()
