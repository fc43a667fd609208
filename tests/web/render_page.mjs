// The page side of render.mjs: loads the GLB and renders it with three.js.
//
// Modes
//   "lightmap": the engine-neutral mapping. Each node's extras.hirad_lightmap names an RGBM PNG
//     in the GLB; it is decoded here to linear floats (value = r/255 * a/255 * range, in
//     W/(m^2 sr) = H/pi), uploaded as a half-float texture and bound as the material's
//     lightMap on TEXCOORD_1 (texture.channel = 1) with the node's rectangle as the texture's
//     offset/repeat. three.js (r187, lights_fragment_maps.glsl.js) adds
//     texel * lightMapIntensity to the irradiance and shades it with BRDF_Lambert = albedo/pi,
//     so lightMapIntensity = pi gives albedo * H/pi, the exitant radiance of a Lambertian surface.
//     The emissive mapping the exporter also wrote (extras.hirad_emissive_is_lightmap) is
//     removed, so the light is counted once.
//   "emissive": the GLB exactly as loaded, no script: the emissive mapping alone (emissive
//     texture on TEXCOORD_1 with KHR_texture_transform, times the albedo, times
//     KHR_materials_emissive_strength).
// lambertian: true replaces each material by a MeshPhysicalMaterial with specularIntensity 0:
//   three.js's standard material takes the F0 = 0.04 dielectric lobe's share out of the diffuse
//   (RE_IndirectDiffuse_Physical's 1 - singleScattering - multiScattering), which hirad's
//   Lambertian transport does not have.
// The picture is rendered into a float render target (linear, no tone mapping, no output
// transfer: three.js applies those only when drawing to the screen) and returned as floats;
// it is also drawn to the canvas (sRGB, scaled by `exposure`) for screenshots.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// A PNG decoder for 8-bit, non-interlaced RGB/RGBA images (what the exporter writes): the
// browser's own image decoding would premultiply the alpha, which RGBM cannot survive.
// PNG specification (W3C, 2003), sections 9 (filtering) and 11.2 (IHDR, IDAT).
async function decodePng(buffer) {
  const b = new Uint8Array(buffer);
  const dv = new DataView(b.buffer, b.byteOffset, b.byteLength);
  const sig = [137, 80, 78, 71, 13, 10, 26, 10];
  sig.forEach((v, i) => { if (b[i] !== v) throw new Error('not a PNG'); });
  let pos = 8, width = 0, height = 0, channels = 0;
  const idat = [];
  while (pos < b.length) {
    const len = dv.getUint32(pos); const type = String.fromCharCode(...b.subarray(pos + 4, pos + 8));
    const data = b.subarray(pos + 8, pos + 8 + len);
    if (type === 'IHDR') {
      width = dv.getUint32(pos + 8); height = dv.getUint32(pos + 12);
      const depth = data[8], colour = data[9], interlace = data[12];
      if (depth !== 8 || interlace !== 0 || (colour !== 2 && colour !== 6))
        throw new Error(`unsupported PNG (depth ${depth}, colour ${colour}, interlace ${interlace})`);
      channels = colour === 6 ? 4 : 3;
    } else if (type === 'IDAT') idat.push(data);
    else if (type === 'IEND') break;
    pos += 12 + len;
  }
  const raw = await inflate(new Uint8Array(await new Blob(idat).arrayBuffer()));
  const stride = width * channels, out = new Uint8Array(height * stride);
  for (let y = 0; y < height; y++) {
    const f = raw[y * (stride + 1)], src = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    const row = out.subarray(y * stride, (y + 1) * stride), up = y ? out.subarray((y - 1) * stride, y * stride) : null;
    for (let x = 0; x < stride; x++) {
      const a = x >= channels ? row[x - channels] : 0, u = up ? up[x] : 0, c = up && x >= channels ? up[x - channels] : 0;
      let p;
      switch (f) {
        case 0: p = 0; break;
        case 1: p = a; break;
        case 2: p = u; break;
        case 3: p = (a + u) >> 1; break;
        case 4: { const q = a + u - c, pa = Math.abs(q - a), pb = Math.abs(q - u), pc = Math.abs(q - c);
          p = pa <= pb && pa <= pc ? a : pb <= pc ? u : c; break; }
        default: throw new Error(`bad PNG filter ${f}`);
      }
      row[x] = (src[x] + p) & 255;
    }
  }
  return { width, height, channels, data: out };
}

async function lightmapTexture(parser, info) {
  const imageDef = parser.json.images[info.image];
  const bytes = await parser.getDependency('bufferView', imageDef.bufferView);
  const png = await decodePng(bytes);
  if (png.channels !== 4) throw new Error('RGBM page without alpha');
  const n = png.width * png.height, half = new Uint16Array(n * 4);
  for (let i = 0; i < n; i++) {
    const m = png.data[4 * i + 3] / 255 * info.range / 255;
    for (let c = 0; c < 3; c++) half[4 * i + c] = THREE.DataUtils.toHalfFloat(png.data[4 * i + c] * m);
    half[4 * i + 3] = THREE.DataUtils.toHalfFloat(1);
  }
  const tex = new THREE.DataTexture(half, png.width, png.height, THREE.RGBAFormat, THREE.HalfFloatType);
  tex.magFilter = THREE.LinearFilter; tex.minFilter = THREE.LinearFilter;
  tex.wrapS = tex.wrapT = THREE.ClampToEdgeWrapping;
  tex.flipY = false;                 // glTF: the image's first row is v = 0
  tex.colorSpace = THREE.NoColorSpace;
  tex.generateMipmaps = false;
  tex.needsUpdate = true;
  return tex;
}

window.hiradRender = async function (opts) {
  const { url, width, height, mode = 'lightmap', camera: cameraName = null, lambertian = true, exposure = 1 } = opts;
  const gltf = await new GLTFLoader().loadAsync(url);
  const scene = gltf.scene, parser = gltf.parser;
  const pages = new Map();
  const objects = [];
  scene.traverse((o) => { if (o.isMesh) objects.push(o); });
  const stats = { meshes: objects.length, lightmapped: 0 };
  for (const o of objects) {
    let mat = o.material;
    if (lambertian) {
      const p = new THREE.MeshPhysicalMaterial({
        color: mat.color, map: mat.map, metalness: mat.metalness, roughness: mat.roughness,
        emissive: mat.emissive, emissiveMap: mat.emissiveMap, emissiveIntensity: mat.emissiveIntensity,
        opacity: mat.opacity, transparent: mat.transparent, side: mat.side, specularIntensity: 0,
      });
      p.userData = mat.userData;
      mat = p;
    } else mat = mat.clone();
    const info = o.userData.hirad_lightmap || (o.parent && o.parent.userData.hirad_lightmap);
    if (mode === 'lightmap') {
      if (mat.userData.hirad_emissive_is_lightmap) { mat.emissiveMap = null; mat.emissive.setRGB(0, 0, 0); }
      if (info) {
        if (!pages.has(info.image)) pages.set(info.image, await lightmapTexture(parser, info));
        const tex = pages.get(info.image).clone();
        tex.channel = 1;
        tex.repeat.set(info.scaleOffset[0], info.scaleOffset[1]);
        tex.offset.set(info.scaleOffset[2], info.scaleOffset[3]);
        tex.needsUpdate = true;
        mat.lightMap = tex;
        mat.lightMapIntensity = Math.PI;
        stats.lightmapped++;
      }
    }
    o.material = mat;
  }
  let cam = null;
  // three.js sanitises node names ('/' is dropped): the USD path is in the node's extras
  const pathOf = (o) => o.userData.hirad_path || (o.parent && o.parent.userData.hirad_path);
  scene.traverse((o) => { if (o.isCamera && !cam && (!cameraName || pathOf(o) === cameraName)) cam = o; });
  if (!cam) throw new Error(`camera ${cameraName} not in the GLB (${gltf.cameras.map(pathOf).join(', ')})`);
  cam.aspect = width / height;
  cam.updateProjectionMatrix();
  scene.updateMatrixWorld(true);

  const canvas = document.createElement('canvas');
  canvas.width = width; canvas.height = height;
  canvas.style.width = `${width}px`; canvas.style.height = `${height}px`;
  document.body.appendChild(canvas);
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(width, height, false);
  renderer.setClearColor(0x000000, 1);
  const target = new THREE.WebGLRenderTarget(width, height, { type: THREE.FloatType, format: THREE.RGBAFormat,
    minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter, depthBuffer: true });
  renderer.setRenderTarget(target);
  renderer.render(scene, cam);
  const px = new Float32Array(width * height * 4);
  renderer.readRenderTargetPixels(target, 0, 0, width, height, px);
  renderer.setRenderTarget(null);
  renderer.toneMapping = THREE.LinearToneMapping;
  renderer.toneMappingExposure = exposure;
  renderer.outputColorSpace = THREE.SRGBColorSpace;
  renderer.render(scene, cam);
  // rows come bottom-up from WebGL: return them top-down, RGB only
  const rgb = new Array(width * height * 3);
  for (let y = 0; y < height; y++) for (let x = 0; x < width; x++)
    for (let c = 0; c < 3; c++) rgb[(y * width + x) * 3 + c] = px[((height - 1 - y) * width + x) * 4 + c];
  const gl = renderer.getContext();
  stats.renderer = gl.getParameter(gl.getExtension('WEBGL_debug_renderer_info')?.UNMASKED_RENDERER_WEBGL ?? gl.RENDERER);
  stats.three = THREE.REVISION;
  return { rgb, stats };
};
window.hiradReady = true;
