"""A Bitterli scene (Mitsuba 0.x syntax) -> the shared scenes' Mitsuba 3 subset, for the stop-63 comparisons:
snake_case names, <lookat>, film W x H with a box filter, path max_depth -1, independent sampler, masks and
bump maps replaced by their nested BSDF, an envmap by a constant emitter, shapes and textures whose files are
missing dropped / made 0.5 grey.

    python convert_bitterli.py SRC.xml DST.xml W H [ENV_RADIANCE]

Scenes from jgarciapueyo/mitsuba2-transient-scenes (ab67c4c...): bathroom 400 225, kitchen 400 225,
staircase 288 512, veach_mi 384 256, cbox-spheres 256 256; references: Mitsuba 3.9.1 scalar_rgb, path,
1024 spp (veach_mi 2048)."""
import re, sys, os
import xml.etree.ElementTree as ET
src, dst, W, H = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
env_const = sys.argv[5] if len(sys.argv) > 5 else "1.0"
base = os.path.dirname(src)
tree = ET.parse(src); root = tree.getroot()
root.set("version", "3.0.0")
def snake(s):
    return re.sub(r"(?<=[a-z0-9])([A-Z])", lambda m: "_" + m.group(1).lower(), s)
RENAME = {"toWorld": "to_world", "intIOR": "int_ior", "extIOR": "ext_ior", "maxDepth": "max_depth",
          "sampleCount": "sample_count", "filterType": "filter_type", "fileFormat": "file_format",
          "pixelFormat": "pixel_format", "specularReflectance": "specular_reflectance",
          "diffuseReflectance": "diffuse_reflectance", "specularTransmittance": "specular_transmittance",
          "faceNormals": "face_normals", "flipNormals": "flip_normals", "alphaU": "alpha_u", "alphaV": "alpha_v"}
for el in root.iter("lookAt"):
    el.tag = "lookat"
for el in root.iter():
    n = el.get("name")
    if n is not None:
        el.set("name", RENAME.get(n, snake(n)))
parent = {c: p for p in root.iter() for c in p}
# masks -> nested bsdf
for el in list(root.iter("bsdf")):
    if el.get("type") == "mask":
        inner = [c for c in el if c.tag == "bsdf"][0]
        if el.get("id"):
            inner.set("id", el.get("id"))
        p = parent[el]; i = list(p).index(el); p.remove(el); p.insert(i, inner)
parent = {c: p for p in root.iter() for c in p}
for el in list(root.iter("bsdf")):  # unused bumpmap wrappers: keep inner only
    if el.get("type") == "bumpmap":
        inner = [c for c in el if c.tag == "bsdf"][0]
        p = parent[el]; i = list(p).index(el); p.remove(el); p.insert(i, inner)
parent = {c: p for p in root.iter() for c in p}
for sh in list(root.iter("shape")):
    fn = [c for c in sh if c.tag == "string" and c.get("name") == "filename"]
    if fn and not os.path.exists(os.path.join(base, fn[0].get("value"))):
        parent[sh].remove(sh); print("dropped", fn[0].get("value"))
for em in list(root.iter("emitter")):
    if em.get("type") == "envmap":
        p = parent[em]; i = list(p).index(em); p.remove(em)
        c = ET.Element("emitter", {"type": "constant"}); ET.SubElement(c, "rgb", {"name": "radiance", "value": env_const})
        p.insert(i, c)
for tex in root.iter("texture"):  # textures whose files are missing -> constant 0.5
    fn = [c for c in tex if c.tag == "string" and c.get("name") == "filename"]
    if fn and not os.path.exists(os.path.join(base, fn[0].get("value"))):
        print("missing texture", fn[0].get("value"))
        p = parent[tex]; i = list(p).index(tex); p.remove(tex)
        p.insert(i, ET.Element("rgb", {"name": tex.get("name"), "value": "0.5"}))
integ = root.find("integrator")
for c in list(integ): integ.remove(c)
integ.set("type", "path"); ET.SubElement(integ, "integer", {"name": "max_depth", "value": "-1"})
sensor = root.find("sensor")
film = sensor.find("film")
for c in list(film): film.remove(c)
ET.SubElement(film, "integer", {"name": "width", "value": str(W)}); ET.SubElement(film, "integer", {"name": "height", "value": str(H)})
ET.SubElement(film, "rfilter", {"type": "box"})
smp = sensor.find("sampler")
for c in list(smp): smp.remove(c)
smp.set("type", "independent"); ET.SubElement(smp, "integer", {"name": "sample_count", "value": "64"})
tree.write(dst, encoding="utf-8", xml_declaration=True)
