// hirad lightmaps -> Unity: menu Tools > hirad > Import Lightmaps...
//
// Reads hirad's OUT/lightmaps/manifest.json (version 2, written by tools/hirad/outputs/
// lightmaps.py) and the page EXRs it lists, and binds them to the active scene's MeshRenderers
// without a Unity bake:
//   1. copies each page (and its direction map, when the manifest lists one) into
//      Assets/HiradLightmaps/<bake>/ (through a temporary name and a rename) and imports it with
//      TextureImporterType.Lightmap (TextureImporterType.DirectionalLightmap for directions),
//      clamped, at its full size;
//   2. LightmapSettings.lightmaps[k] = LightmapData { lightmapColor = page k, lightmapDir = its
//      direction map or none }; LightmapSettings.lightmapsMode = CombinedDirectional when every
//      page has a direction map, else NonDirectional;
//   3. per manifest instance, the renderer of its prim (rule below): lightmapIndex = page,
//      lightmapScaleOffset = scaleOffset as written.
//   4. keeps all of it in a HiradLightmaps component (Runtime/HiradLightmaps.cs) on a GameObject
//      "hirad lightmaps" of the active scene, which re-applies it on every load: Unity does not
//      serialise lightmapScaleOffset in editor scenes (Scripting Reference,
//      Renderer.lightmapScaleOffset).
//
// Conventions. hirad's scaleOffset is already Unity's: page_uv = uv * (x, y) + (z, w), the
// order of Renderer.lightmapScaleOffset and unity_LightmapST. Unity's UV origin is bottom-left,
// like USD's, so the manifest's engines.unity.flipV is false and nothing is flipped: the mesh's
// UV2 (Unity's uv2 channel, TEXCOORD1) must be the mesh's own lightmap set st1 as USD has it.
// hirad's GLB (tools/hirad/outputs/gltf.py) writes st1 as glTF TEXCOORD_1 = (u, 1 - v), and
// glTF importers for Unity (glTFast, UnityGLTF) turn glTF UVs back into Unity's with
// v' = 1 - v, so uv2 = st1 exactly. Turn OFF "Generate Lightmap UVs" for any model importer
// that has it: it replaces uv2 and the rectangles no longer fit.
// The page values are incident radiance H/pi in W/(m^2 sr) (what a white Lambertian surface
// reflects); Unity multiplies a lightmap texel by the albedo, so they go in unscaled.
//
// Which renderer is which prim (first rule with any match wins; two matches are an error):
//   1. the GameObject's name is the prim path ("/World/box"): hirad's GLB names every node by
//      its prim path and glTF importers keep node names;
//   2. the GameObject's hierarchy path, "/" + the names from its scene root down to it, is the
//      prim path or ends with it (".../World/box"): a hierarchy that mirrors the USD prims, e.g.
//      Unity's USD importer, or a glTF whose node names are the prim names.
//
// Every manifest key is read through Req (must exist, of that kind) or Opt (may be absent);
// tests/python/outputs/test_engine_scripts.py reads those calls out of this file and checks
// them against a real bake's manifest.
//
// Not done here: Unity's light probes (hirad writes SphericalHarmonicsL2 data beside its
// volume; LightProbes assets are not created), shadowmasks, RGBM/dLDR pages (hirad's EXRs are
// imported and Unity encodes them per the project's lightmap encoding).

#if UNITY_EDITOR
using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Text;
using UnityEditor;
using UnityEditor.SceneManagement;
using UnityEngine;
using UnityEngine.Rendering;
using UnityEngine.SceneManagement;

namespace Hirad.Engines
{
    public sealed class HiradImportException : Exception
    {
        public HiradImportException(string message) : base(message) { }
    }

    public static class HiradLightmapImporter
    {
        public const int ManifestVersion = 2;
        public const string DefaultAssetFolder = "Assets/HiradLightmaps";

        [MenuItem("Tools/hirad/Import Lightmaps...")]
        static void ImportFromMenu()
        {
            string path = EditorUtility.OpenFilePanel("hirad lightmap manifest (OUT/lightmaps/manifest.json)", "", "json");
            if (string.IsNullOrEmpty(path))
                return;
            try
            {
                var bound = Import(path, DefaultAssetFolder);
                Debug.Log($"hirad: {bound.renderers.Length} renderers lightmapped from {bound.colors.Length} pages ({path}); save the scene to keep them");
            }
            catch (HiradImportException e)
            {
                Debug.LogError("hirad: " + e.Message);
                EditorUtility.DisplayDialog("hirad lightmaps", e.Message, "OK");
            }
        }

        /// <summary>Imports the pages of one manifest and binds them to the active scene's
        /// renderers; returns the HiradLightmaps component that holds the binding.</summary>
        public static HiradLightmaps Import(string manifestPath, string assetFolder)
        {
            var manifest = ReadManifest(manifestPath);
            string where = manifestPath;
            string baseDir = Path.GetDirectoryName(Path.GetFullPath(manifestPath));

            // ---- the manifest's conventions, checked against what this importer assumes
            long version = (long)Req(manifest, "version", "int", where);
            if (version != ManifestVersion)
                throw new HiradImportException($"{where}: version {version}; this importer reads version {ManifestVersion}");
            string origin = (string)Req(manifest, "uvOrigin", "string", where);
            if (!origin.StartsWith("bottom-left", StringComparison.Ordinal))
                throw new HiradImportException($"{where}: uvOrigin is \"{origin}\"; scaleOffset is used as is only for bottom-left (USD) UVs");
            var engines = (Dictionary<string, object>)Req(manifest, "engines", "dict", where);
            var unity = (Dictionary<string, object>)Req(engines, "unity", "dict", where + ": engines");
            if ((bool)Req(unity, "flipV", "bool", where + ": engines.unity"))
                throw new HiradImportException($"{where}: engines.unity.flipV is true; this importer applies no flip");

            // ---- pages: checked here, copied and imported once every instance has matched
            var pageList = (List<object>)Req(manifest, "pages", "array", where);
            int pageCount = pageList.Count;
            var pageFiles = new string[pageCount];
            var dirFiles = new string[pageCount];
            var sizes = new long[pageCount, 2];
            int withDir = 0;
            for (int k = 0; k < pageCount; k++)
            {
                string pw = $"{where}: pages[{k}]";
                var page = pageList[k] as Dictionary<string, object>;
                if (page == null)
                    throw new HiradImportException($"{pw} is not an object");
                pageFiles[k] = Path.Combine(baseDir, (string)Req(page, "file", "string", pw));
                sizes[k, 0] = (long)Req(page, "width", "int", pw);
                sizes[k, 1] = (long)Req(page, "height", "int", pw);
                object dirFile = Opt(page, "unityDirection", "string", pw);
                if (dirFile != null)
                {
                    dirFiles[k] = Path.Combine(baseDir, (string)dirFile);
                    withDir++;
                }
            }
            if (withDir != 0 && withDir != pageCount)
                throw new HiradImportException($"{where}: {withDir} of {pageCount} pages have a unityDirection map; all or none must");

            // ---- instances -> renderers
            var candidates = SceneRenderers();
            var instances = (List<object>)Req(manifest, "instances", "array", where);
            var renderers = new List<MeshRenderer>();
            var pages = new List<int>();
            var rects = new List<Vector4>();
            var prims = new List<string>();
            var taken = new Dictionary<MeshRenderer, string>();
            var missing = new List<string>();
            var problems = new List<string>();
            for (int i = 0; i < instances.Count; i++)
            {
                string iw = $"{where}: instances[{i}]";
                var inst = instances[i] as Dictionary<string, object>;
                if (inst == null)
                    throw new HiradImportException($"{iw} is not an object");
                string prim = (string)Req(inst, "prim", "string", iw);
                long page = (long)Req(inst, "page", "int", iw);
                var so = (double[])Req(inst, "scaleOffset", "number4", iw);
                if (page < 0 || page >= pageCount)
                    throw new HiradImportException($"{iw} ({prim}): page {page}, the manifest has {pageCount} pages");
                var found = FindRenderers(prim, candidates);
                if (found.Count == 0)
                {
                    missing.Add(prim);
                    continue;
                }
                if (found.Count > 1)
                {
                    var names = new List<string>();
                    foreach (var r in found)
                        names.Add(HierarchyPath(r.transform));
                    problems.Add($"{iw}: {prim} matches {found.Count} renderers ({string.Join(", ", names)})");
                    continue;
                }
                var renderer = found[0];
                if (taken.TryGetValue(renderer, out string other))
                {
                    problems.Add($"{iw}: {other} and {prim} both match {HierarchyPath(renderer.transform)}");
                    continue;
                }
                taken[renderer] = prim;
                var filter = renderer.GetComponent<MeshFilter>();
                var mesh = filter != null ? filter.sharedMesh : null;
                if (mesh == null || !mesh.HasVertexAttribute(VertexAttribute.TexCoord1))
                {
                    problems.Add($"{iw}: {HierarchyPath(renderer.transform)} ({prim}) has no UV2 (TEXCOORD1); import hirad's GLB, which carries st1 as TEXCOORD_1");
                    continue;
                }
                renderers.Add(renderer);
                pages.Add((int)page);
                rects.Add(new Vector4((float)so[0], (float)so[1], (float)so[2], (float)so[3]));
                prims.Add(prim);
            }
            if (problems.Count > 0)
                throw new HiradImportException(string.Join("\n", problems));
            if (renderers.Count == 0)
                throw new HiradImportException($"{where}: no instance matched a MeshRenderer of the active scene");
            if (missing.Count > 0)
                Debug.LogWarning($"hirad: {missing.Count} manifest instances have no renderer in the active scene and get no lightmap: " +
                                 string.Join(", ", missing.GetRange(0, Math.Min(8, missing.Count))) + (missing.Count > 8 ? " ..." : ""));

            // ---- the pages into the project
            string bakeName = SafeName(Path.GetFileName(Path.GetDirectoryName(baseDir)) ?? "bake");
            string folder = (assetFolder.TrimEnd('/') + "/" + bakeName).Replace('\\', '/');
            Directory.CreateDirectory(Path.Combine(ProjectRoot(), folder));
            var colors = new Texture2D[pageCount];
            var dirs = new Texture2D[pageCount];
            for (int k = 0; k < pageCount; k++)
            {
                string pw = $"{where}: pages[{k}]";
                colors[k] = ImportPage(pageFiles[k], folder, TextureImporterType.Lightmap, sizes[k, 0], sizes[k, 1], pw);
                if (dirFiles[k] != null)
                    dirs[k] = ImportPage(dirFiles[k], folder, TextureImporterType.DirectionalLightmap, sizes[k, 0], sizes[k, 1], pw + ".unityDirection");
            }

            // ---- bind, and keep the binding in the scene
            var active = SceneManager.GetActiveScene();
            HiradLightmaps holder = null;
            foreach (var root in active.GetRootGameObjects())
            {
                holder = root.GetComponentInChildren<HiradLightmaps>(true);
                if (holder != null)
                    break;
            }
            if (holder == null)
            {
                var go = new GameObject("hirad lightmaps");
                Undo.RegisterCreatedObjectUndo(go, "hirad lightmaps");
                holder = go.AddComponent<HiradLightmaps>();
            }
            Undo.RecordObject(holder, "hirad lightmaps");
            foreach (var r in renderers)
                Undo.RecordObject(r, "hirad lightmaps");
            holder.manifest = Path.GetFullPath(manifestPath);
            holder.colors = colors;
            holder.directions = withDir == pageCount ? dirs : new Texture2D[0];
            holder.renderers = renderers.ToArray();
            holder.pages = pages.ToArray();
            holder.scaleOffsets = rects.ToArray();
            holder.prims = prims.ToArray();
            holder.Apply();
            EditorUtility.SetDirty(holder);
            EditorSceneManager.MarkSceneDirty(holder.gameObject.scene);
            return holder;
        }

        // ------------------------------------------------------------------------------------
        // Pages

        static string ProjectRoot()
        {
            return Path.GetDirectoryName(Application.dataPath);
        }

        static string SafeName(string name)
        {
            var sb = new StringBuilder();
            foreach (char c in name)
                sb.Append(char.IsLetterOrDigit(c) || c == '-' || c == '_' ? c : '_');
            return sb.Length > 0 ? sb.ToString() : "bake";
        }

        /// <summary>Copies a page into the project (temporary name, then a rename) and imports it
        /// as a lightmap of its full size; the imported size is checked against the manifest's.</summary>
        static Texture2D ImportPage(string source, string folder, TextureImporterType type, long width, long height, string where)
        {
            if (!File.Exists(source))
                throw new HiradImportException($"{where}: {source} does not exist");
            string assetPath = folder + "/" + Path.GetFileName(source);
            string target = Path.Combine(ProjectRoot(), assetPath);
            if (Path.GetFullPath(source) != Path.GetFullPath(target))
            {
                string tmp = target + ".partial";
                File.Copy(source, tmp, true);
                if (File.Exists(target))
                    File.Delete(target);
                File.Move(tmp, target);
            }
            AssetDatabase.ImportAsset(assetPath, ImportAssetOptions.ForceSynchronousImport);
            var importer = AssetImporter.GetAtPath(assetPath) as TextureImporter;
            if (importer == null)
                throw new HiradImportException($"{where}: Unity did not import {assetPath} as a texture");
            long side = Math.Max(width, height);
            int max = 32;
            while (max < side && max < 16384)
                max *= 2;
            importer.textureType = type;
            importer.wrapMode = TextureWrapMode.Clamp;
            importer.maxTextureSize = max;
            importer.npotScale = TextureImporterNPOTScale.None;
            importer.SaveAndReimport();
            var tex = AssetDatabase.LoadAssetAtPath<Texture2D>(assetPath);
            if (tex == null)
                throw new HiradImportException($"{where}: {assetPath} did not load as a Texture2D");
            if (tex.width != width || tex.height != height)
                throw new HiradImportException($"{where}: {assetPath} imported as {tex.width}x{tex.height}, the manifest says {width}x{height}");
            return tex;
        }

        // ------------------------------------------------------------------------------------
        // Renderers

        static List<MeshRenderer> SceneRenderers()
        {
            // the active scene only: the binding component lives there, and Unity does not
            // serialise references from one scene into another
            var list = new List<MeshRenderer>();
            foreach (var root in SceneManager.GetActiveScene().GetRootGameObjects())
                list.AddRange(root.GetComponentsInChildren<MeshRenderer>(true));
            return list;
        }

        public static string HierarchyPath(Transform t)
        {
            var parts = new List<string>();
            for (; t != null; t = t.parent)
                parts.Add(t.name);
            parts.Reverse();
            return "/" + string.Join("/", parts);
        }

        static List<MeshRenderer> FindRenderers(string prim, List<MeshRenderer> candidates)
        {
            var byName = new List<MeshRenderer>();
            var byPath = new List<MeshRenderer>();
            foreach (var r in candidates)
            {
                if (r.gameObject.name == prim)
                    byName.Add(r);
                string path = HierarchyPath(r.transform);
                if (prim.StartsWith("/", StringComparison.Ordinal) && path.EndsWith(prim, StringComparison.Ordinal))
                    byPath.Add(r);
            }
            return byName.Count > 0 ? byName : byPath;
        }

        // ------------------------------------------------------------------------------------
        // The manifest: JSON into Dictionary<string, object> / List<object> / double / string /
        // bool / null, and the two accessors every key goes through.

        static Dictionary<string, object> ReadManifest(string path)
        {
            string text;
            try
            {
                text = File.ReadAllText(path, Encoding.UTF8);
            }
            catch (Exception e)
            {
                throw new HiradImportException($"{path}: cannot be read ({e.Message})");
            }
            var parser = new Json(text, path);
            var value = parser.ParseDocument();
            var dict = value as Dictionary<string, object>;
            if (dict == null)
                throw new HiradImportException($"{path}: the top level is not a JSON object");
            return dict;
        }

        /// <summary>d[key], which must exist and be of `kind` (string, bool, number, int, array,
        /// dict, number4); ints come back as long, number4 as double[4].</summary>
        static object Req(Dictionary<string, object> d, string key, string kind, string where)
        {
            if (!d.TryGetValue(key, out object v))
                throw new HiradImportException($"{where} has no \"{key}\"");
            return Convert(v, key, kind, where);
        }

        /// <summary>d[key] of `kind` when present, else null.</summary>
        static object Opt(Dictionary<string, object> d, string key, string kind, string where)
        {
            if (!d.TryGetValue(key, out object v) || v == null)
                return null;
            return Convert(v, key, kind, where);
        }

        static object Convert(object v, string key, string kind, string where)
        {
            string bad = $"{where}.{key} is {Describe(v)}, expected {kind}";
            switch (kind)
            {
                case "string":
                    if (v is string) return v;
                    break;
                case "bool":
                    if (v is bool) return v;
                    break;
                case "number":
                    if (v is double) return v;
                    break;
                case "int":
                    if (v is double x && Math.Floor(x) == x && Math.Abs(x) < 9e15) return (long)x;
                    break;
                case "array":
                    if (v is List<object>) return v;
                    break;
                case "dict":
                    if (v is Dictionary<string, object>) return v;
                    break;
                case "number4":
                    if (v is List<object> list && list.Count == 4)
                    {
                        var a = new double[4];
                        for (int i = 0; i < 4; i++)
                        {
                            if (!(list[i] is double e))
                                throw new HiradImportException(bad);
                            a[i] = e;
                        }
                        return a;
                    }
                    break;
                default:
                    throw new ArgumentException("unknown kind " + kind);
            }
            throw new HiradImportException(bad);
        }

        static string Describe(object v)
        {
            switch (v)
            {
                case null: return "null";
                case string _: return "a string";
                case bool _: return "a boolean";
                case double _: return "a number";
                case List<object> l: return $"an array of {l.Count}";
                case Dictionary<string, object> _: return "an object";
                default: return v.GetType().Name;
            }
        }

        /// <summary>A strict JSON (RFC 8259) reader; errors name the file, line and column.</summary>
        sealed class Json
        {
            readonly string s;
            readonly string file;
            int i;

            public Json(string text, string file)
            {
                s = text;
                this.file = file;
            }

            public object ParseDocument()
            {
                object v = Value();
                Space();
                if (i != s.Length)
                    Fail("text after the JSON value");
                return v;
            }

            void Fail(string what)
            {
                int line = 1, col = 1;
                for (int k = 0; k < i && k < s.Length; k++)
                {
                    if (s[k] == '\n') { line++; col = 1; }
                    else col++;
                }
                throw new HiradImportException($"{file}:{line}:{col}: {what}");
            }

            void Space()
            {
                while (i < s.Length && (s[i] == ' ' || s[i] == '\t' || s[i] == '\n' || s[i] == '\r'))
                    i++;
            }

            object Value()
            {
                Space();
                if (i >= s.Length)
                    Fail("unexpected end of the file");
                char c = s[i];
                if (c == '{') return Object();
                if (c == '[') return Array();
                if (c == '"') return String();
                if (c == '-' || (c >= '0' && c <= '9')) return Number();
                if (Word("true")) return true;
                if (Word("false")) return false;
                if (Word("null")) return null;
                Fail($"unexpected '{c}'");
                return null;
            }

            bool Word(string w)
            {
                if (string.CompareOrdinal(s, i, w, 0, w.Length) != 0)
                    return false;
                i += w.Length;
                return true;
            }

            Dictionary<string, object> Object()
            {
                var d = new Dictionary<string, object>();
                i++;
                Space();
                if (i < s.Length && s[i] == '}') { i++; return d; }
                while (true)
                {
                    Space();
                    if (i >= s.Length || s[i] != '"')
                        Fail("expected a key string");
                    string key = String();
                    Space();
                    if (i >= s.Length || s[i] != ':')
                        Fail("expected ':'");
                    i++;
                    d[key] = Value();
                    Space();
                    if (i < s.Length && s[i] == ',') { i++; continue; }
                    if (i < s.Length && s[i] == '}') { i++; return d; }
                    Fail("expected ',' or '}'");
                }
            }

            List<object> Array()
            {
                var list = new List<object>();
                i++;
                Space();
                if (i < s.Length && s[i] == ']') { i++; return list; }
                while (true)
                {
                    list.Add(Value());
                    Space();
                    if (i < s.Length && s[i] == ',') { i++; continue; }
                    if (i < s.Length && s[i] == ']') { i++; return list; }
                    Fail("expected ',' or ']'");
                }
            }

            string String()
            {
                var sb = new StringBuilder();
                i++;
                while (true)
                {
                    if (i >= s.Length)
                        Fail("unterminated string");
                    char c = s[i++];
                    if (c == '"')
                        return sb.ToString();
                    if (c < 0x20)
                        Fail("control character in a string");
                    if (c != '\\') { sb.Append(c); continue; }
                    if (i >= s.Length)
                        Fail("unterminated escape");
                    char e = s[i++];
                    switch (e)
                    {
                        case '"': sb.Append('"'); break;
                        case '\\': sb.Append('\\'); break;
                        case '/': sb.Append('/'); break;
                        case 'b': sb.Append('\b'); break;
                        case 'f': sb.Append('\f'); break;
                        case 'n': sb.Append('\n'); break;
                        case 'r': sb.Append('\r'); break;
                        case 't': sb.Append('\t'); break;
                        case 'u':
                            int code = 0;
                            if (i + 4 > s.Length || !int.TryParse(s.Substring(i, 4), NumberStyles.HexNumber, CultureInfo.InvariantCulture, out code))
                                Fail("bad \\u escape");
                            sb.Append((char)code);
                            i += 4;
                            break;
                        default:
                            Fail($"bad escape '\\{e}'");
                            break;
                    }
                }
            }

            double Number()
            {
                int start = i;
                if (s[i] == '-') i++;
                while (i < s.Length && "0123456789+-.eE".IndexOf(s[i]) >= 0)
                    i++;
                string t = s.Substring(start, i - start);
                if (!double.TryParse(t, NumberStyles.Float, CultureInfo.InvariantCulture, out double v))
                {
                    i = start;
                    Fail($"bad number '{t}'");
                }
                return v;
            }
        }
    }
}
#endif
