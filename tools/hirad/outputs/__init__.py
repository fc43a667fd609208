"""The outputs of a bake, each from the solution: `meshes` (the solution meshes for the USD
layer), `lightmaps` (atlas pages), `volume` (the OpenVDB irradiance volume), `images`
(preview renders and tone mapping), `lightmap_render` (rendering from the lightmaps alone).
"""
