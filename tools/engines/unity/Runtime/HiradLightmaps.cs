// hirad lightmaps in a Unity scene: the per-renderer binding that Unity does not keep by itself.
//
// Unity serialises Renderer.lightmapScaleOffset only into player builds; in the editor "it's the
// responsibility of the Unity lightmapping system (or a custom script that brings external
// lightmapping data) to set it when the Scene loads or playmode is entered" (Unity Scripting
// Reference, Renderer.lightmapScaleOffset). This component is that script: the editor importer
// (Editor/HiradLightmapImporter.cs) fills it once from hirad's manifest, and it writes
// LightmapSettings.lightmaps, LightmapSettings.lightmapsMode and every bound renderer's
// lightmapIndex / lightmapScaleOffset again whenever it is enabled (scene load, play mode, domain
// reload; [ExecuteAlways] so in edit mode too).
//
// The data are hirad's unchanged: page k of the manifest is LightmapSettings.lightmaps[k]
// (lightmapColor = the page EXR, lightmapDir = its direction map when the manifest lists one),
// and lightmapScaleOffset = the manifest's scaleOffset (Unity's own order, page_uv = uv2 * xy +
// zw, both in Unity's UV convention: origin bottom-left like USD, so nothing is flipped).
// Values are incident radiance H/pi in W/(m^2 sr), the light a white Lambertian surface
// reflects; Unity multiplies the lightmap by the albedo, so they go in unscaled.
//
// Limits: it replaces the scene's whole lightmap array (one hirad bake per loaded scene; scenes
// loaded additively with their own lightmaps are not merged), and a Unity bake (Generate
// Lighting) of the same scene overwrites these settings until this component is re-enabled.

using UnityEngine;

namespace Hirad.Engines
{
    [ExecuteAlways]
    [DisallowMultipleComponent]
    [AddComponentMenu("hirad/hirad Lightmaps")]
    public sealed class HiradLightmaps : MonoBehaviour
    {
        [Tooltip("The manifest this was imported from (for the record).")]
        public string manifest;

        [Tooltip("One per hirad page: the colour lightmap (incident radiance / pi, linear).")]
        public Texture2D[] colors = new Texture2D[0];

        [Tooltip("One per hirad page, or empty: the dominant-direction map (Directional mode).")]
        public Texture2D[] directions = new Texture2D[0];

        [Tooltip("Bound renderers; pages[i] and scaleOffsets[i] belong to renderers[i].")]
        public MeshRenderer[] renderers = new MeshRenderer[0];

        public int[] pages = new int[0];

        [Tooltip("Unity order: page_uv = uv2 * (x, y) + (z, w).")]
        public Vector4[] scaleOffsets = new Vector4[0];

        [Tooltip("The manifest prim path of each bound renderer (for the record).")]
        public string[] prims = new string[0];

        void OnEnable()
        {
            Apply();
        }

        /// <summary>Writes the lightmap array and every renderer's index and rectangle.</summary>
        public void Apply()
        {
            if (colors == null || colors.Length == 0)
                return;
            bool directional = directions != null && directions.Length == colors.Length;
            var data = new LightmapData[colors.Length];
            for (int k = 0; k < colors.Length; k++)
            {
                data[k] = new LightmapData { lightmapColor = colors[k] };
                if (directional)
                    data[k].lightmapDir = directions[k];
            }
            LightmapSettings.lightmapsMode = directional ? LightmapsMode.CombinedDirectional : LightmapsMode.NonDirectional;
            LightmapSettings.lightmaps = data;
            int n = Mathf.Min(renderers.Length, Mathf.Min(pages.Length, scaleOffsets.Length));
            for (int i = 0; i < n; i++)
            {
                var r = renderers[i];
                if (r == null)
                    continue;
                if (pages[i] < 0 || pages[i] >= colors.Length)
                {
                    Debug.LogWarning($"hirad: {r.name}: page {pages[i]} is outside the {colors.Length} lightmaps", r);
                    continue;
                }
                r.lightmapIndex = pages[i];
                r.lightmapScaleOffset = scaleOffsets[i];
            }
        }
    }
}
