"""Standalone HTML export of a viewer scene: the plotter's actors drawn by a small inline WebGL script.

PyVista's own ``export_html`` needs trame (a web server stack we do not ship), so the scene is
exported here: each visible 3D actor becomes triangles, line segments or points with per-vertex
colours (the mapper's own colour mapping, so heat maps look as on screen) or a texture (camera
images), packed as base64 float32/uint32 arrays inside the page. The page needs no server, no CDN and
no network; it opens from disk. It writes its state into ``<body data-viewer-status=...>`` so a
headless browser (``--dump-dom``) can check it drew.
"""

from __future__ import annotations

import base64
import html
import io
import json
import logging
from pathlib import Path

import numpy as np

from bodystudio.errors import InputError
from bodystudio.fileio import atomic_write
from bodystudio.viewer.scene import BACKGROUND, EmptySceneError

log = logging.getLogger(__name__)

_REPRESENTATION_POINTS, _REPRESENTATION_WIREFRAME = 0, 1


def _b64(array: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def _png_data_url(image: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _cell_arrays(cells: np.ndarray) -> list[np.ndarray]:
    """Split a VTK cell array ``[n, i0, .., n, j0, ..]`` into index arrays."""
    out, k = [], 0
    cells = np.asarray(cells, dtype=np.int64)
    while k < len(cells):
        n = int(cells[k])
        out.append(cells[k + 1:k + 1 + n])
        k += n + 1
    return out


def _segments(cells: np.ndarray, closed: bool) -> np.ndarray:
    segs = []
    for ids in _cell_arrays(cells):
        if len(ids) < 2:
            continue
        a, b = ids[:-1], ids[1:]
        if closed:
            a, b = ids, np.roll(ids, -1)
        segs.append(np.c_[a, b])
    return np.vstack(segs) if segs else np.zeros((0, 2), dtype=np.int64)


def _n_polys(data) -> int:
    return int(data.GetNumberOfPolys() + data.GetNumberOfStrips())


def _actor_colors(actor, data) -> np.ndarray | None:
    """Per-point RGB (n, 3) uint8 as the mapper colours them, or None for a single colour."""
    mapper = actor.GetMapper()
    if not mapper.GetScalarVisibility():
        return None
    name = mapper.GetArrayName()
    array = data.GetPointData().GetArray(name) if name else data.GetPointData().GetScalars()
    if array is None or array.GetNumberOfTuples() != data.n_points:
        return None
    from vtkmodules.util.numpy_support import vtk_to_numpy

    values = vtk_to_numpy(array)
    if values.dtype == np.uint8 and values.ndim == 2 and values.shape[1] >= 3:
        return np.ascontiguousarray(values[:, :3])  # direct RGB colours
    lut = mapper.GetLookupTable()
    lo, hi = mapper.GetScalarRange()
    lut.SetRange(lo, hi)
    mapped = lut.MapScalars(array, 0, -1 if values.ndim == 1 else 0)  # VTK_COLOR_MODE_DEFAULT
    rgba = vtk_to_numpy(mapped).reshape(mapped.GetNumberOfTuples(), -1)
    return rgba[:, :3].astype(np.uint8)


def _actor_texture(actor, data) -> tuple[str, np.ndarray] | None:
    texture = actor.GetTexture()
    if texture is None or texture.GetInput() is None or data.active_texture_coordinates is None:
        return None
    import pyvista as pv

    img = pv.wrap(texture.GetInput())
    nx, ny, _ = img.dimensions
    pixels = np.asarray(img.active_scalars).reshape(ny, nx, -1)[::-1, :, :3].astype(np.uint8)
    return _png_data_url(pixels), np.asarray(data.active_texture_coordinates, dtype=np.float32)


def scene_payload(plotter, include=None, exclude=(), allow_empty: bool = False) -> dict:
    """The plotter's visible 3D actors, camera and colour bars as a JSON-ready dict for the WebGL page.

    ``include`` / ``exclude`` select actors by name (e.g. the per-frame layers of a session).
    """
    import pyvista as pv
    import vtk

    objects = []
    for name, actor in plotter.renderer.actors.items():
        if (include is not None and name not in include) or name in exclude:
            continue
        if not isinstance(actor, vtk.vtkActor) or not actor.GetVisibility() or actor.GetMapper() is None:
            continue
        mapper = actor.GetMapper()
        raw = mapper.GetInput()
        if raw is not None and raw.GetNumberOfPoints() == 0:
            # a mesh with RGB vertex colours added after the last render: its mapper's input is filled by the
            # pipeline only when it runs (it was dropped from the page when added after the camera was set)
            mapper.Update()
            raw = mapper.GetInput()
        if raw is None or raw.GetNumberOfPoints() == 0:
            continue
        data = pv.wrap(raw)
        if not isinstance(data, pv.PolyData):
            data = data.extract_surface()
        prop = actor.GetProperty()
        colors = _actor_colors(actor, data)
        texture = _actor_texture(actor, data)
        V = np.asarray(data.points, dtype=np.float64)
        obj = {"name": str(name), "positions": _b64(V, "<f4"), "n": int(len(V)),
               "color": [float(c) for c in prop.GetColor()], "opacity": float(prop.GetOpacity()),
               "lighting": bool(prop.GetLighting()), "pointSize": float(prop.GetPointSize())}
        if colors is not None:
            obj["colors"] = _b64(colors, np.uint8)
        if texture is not None:
            obj["texture"], uv = texture
            obj["uv"] = _b64(uv, "<f4")
        rep = prop.GetRepresentation()
        if rep == _REPRESENTATION_POINTS:
            obj["mode"] = "points"
        elif rep == _REPRESENTATION_WIREFRAME or _n_polys(data) == 0:
            segs = _segments(data.lines, closed=False) if data.n_lines else np.zeros((0, 2), np.int64)
            if _n_polys(data):
                segs = np.vstack([segs, _segments(data.faces, closed=True)])
            if len(segs) == 0 and data.n_verts:
                obj["mode"] = "points"
            else:
                obj["mode"], obj["indices"] = "lines", _b64(segs.ravel(), "<u4")
            obj["count"] = int(segs.size)
        else:
            tri = data.triangulate()
            F = np.asarray(tri.faces, dtype=np.int64).reshape(-1, 4)[:, 1:]
            obj["mode"], obj["indices"], obj["count"] = "triangles", _b64(F.ravel(), "<u4"), int(F.size)
        objects.append(obj)
    if not objects and not allow_empty:
        raise EmptySceneError("nothing to export: the scene is empty; give a mesh, avatar or session with data")
    cam = plotter.camera
    bars = []
    for title, bar in plotter.scalar_bars.items():
        lut = bar.GetLookupTable()
        lo, hi = lut.GetRange()
        samples = []
        for k in range(32):
            rgb = [0.0, 0.0, 0.0]
            lut.GetColor(lo + (hi - lo) * k / 31, rgb)
            samples.append([int(round(255 * c)) for c in rgb])
        bars.append({"title": str(title), "min": float(lo), "max": float(hi), "colors": samples})
    return {"objects": objects, "background": list(BACKGROUND),
            "camera": {"position": list(cam.position), "focal": list(cam.focal_point), "up": list(cam.up),
                       "viewAngle": float(cam.view_angle)},
            "colorBars": bars}


VIEWER_CSS = """
.bs-view{position:relative;width:100%;max-width:1100px;aspect-ratio:4/3;background:#292b33;border-radius:6px;overflow:hidden}
.bs-view canvas{width:100%;height:100%;display:block;cursor:grab;touch-action:none}
.bs-help{position:absolute;left:8px;bottom:6px;color:#ddd;font:12px sans-serif;opacity:.8;pointer-events:none}
.bs-msg{position:absolute;left:20px;top:20px;color:#f88;font:14px sans-serif}
.bs-frames{font:13px sans-serif;margin:4px 0 10px}.bs-frames input{width:50%;vertical-align:middle}
.bs-bar{position:absolute;right:10px;top:15%;height:60%;width:130px;color:#eee;font:12px sans-serif;pointer-events:none}
.bs-bar .grad{position:absolute;left:0;top:18px;bottom:0;width:18px;border:1px solid #ccc}
.bs-bar .t{position:absolute;top:0;left:0;white-space:nowrap;font-weight:bold}
.bs-bar .hi{position:absolute;left:24px;top:14px}.bs-bar .lo{position:absolute;left:24px;bottom:-4px}
"""  # noqa: E501  (inline script and style)

# The viewer script: WebGL 1 with OES_element_index_uint, a headlight, orbit / pan / zoom with the mouse.
VIEWER_JS = r"""
(function(){
"use strict";
function b64(s, T){var bin=atob(s),n=bin.length,u=new Uint8Array(n);for(var i=0;i<n;i++)u[i]=bin.charCodeAt(i);return new T(u.buffer);}
function sub(a,b){return [a[0]-b[0],a[1]-b[1],a[2]-b[2]];}
function add(a,b){return [a[0]+b[0],a[1]+b[1],a[2]+b[2]];}
function scl(a,s){return [a[0]*s,a[1]*s,a[2]*s];}
function dot(a,b){return a[0]*b[0]+a[1]*b[1]+a[2]*b[2];}
function crs(a,b){return [a[1]*b[2]-a[2]*b[1],a[2]*b[0]-a[0]*b[2],a[0]*b[1]-a[1]*b[0]];}
function nrm(a){var l=Math.sqrt(dot(a,a))||1;return scl(a,1/l);}
function rot(v,axis,ang){axis=nrm(axis);var c=Math.cos(ang),s=Math.sin(ang);
  return add(add(scl(v,c),scl(crs(axis,v),s)),scl(axis,dot(axis,v)*(1-c)));}
function lookAt(e,t,u){var f=nrm(sub(t,e)),r=nrm(crs(f,u)),up=crs(r,f);
  return [r[0],up[0],-f[0],0, r[1],up[1],-f[1],0, r[2],up[2],-f[2],0, -dot(r,e),-dot(up,e),dot(f,e),1];}
function persp(fovy,asp,n,f){var t=1/Math.tan(fovy/2);
  return [t/asp,0,0,0, 0,t,0,0, 0,0,(f+n)/(n-f),-1, 0,0,2*f*n/(n-f),0];}
function mul(a,b){var o=new Array(16);for(var c=0;c<4;c++)for(var r=0;r<4;r++){var s=0;
  for(var k=0;k<4;k++)s+=a[k*4+r]*b[c*4+k];o[c*4+r]=s;}return o;}
var VS="attribute vec3 p;attribute vec3 nn;attribute vec3 c;attribute vec2 uv;uniform mat4 mvp;uniform mat4 mv;"+
 "uniform float ps;varying vec3 vc;varying vec3 vn;varying vec2 vuv;"+
 "void main(){gl_Position=mvp*vec4(p,1.0);gl_PointSize=ps;vc=c;vn=(mv*vec4(nn,0.0)).xyz;vuv=uv;}";
var FS="precision mediump float;varying vec3 vc;varying vec3 vn;varying vec2 vuv;uniform float lit;uniform float useTex;"+
 "uniform float alpha;uniform sampler2D tex;void main(){vec3 col=useTex>0.5?texture2D(tex,vuv).rgb:vc;"+
 "float s=1.0;if(lit>0.5){vec3 n=normalize(vn);s=0.2+0.8*abs(n.z);}gl_FragColor=vec4(col*s,alpha);}";
function shader(gl,type,src){var s=gl.createShader(type);gl.shaderSource(s,src);gl.compileShader(s);
  if(!gl.getShaderParameter(s,gl.COMPILE_STATUS))throw new Error("shader: "+gl.getShaderInfoLog(s));return s;}
window.bodystudioView=function(canvas, scene){
  var gl=canvas.getContext("webgl",{preserveDrawingBuffer:true,antialias:true})||canvas.getContext("experimental-webgl",{preserveDrawingBuffer:true});
  if(!gl)throw new Error("WebGL is not available in this browser");
  var u32=gl.getExtension("OES_element_index_uint");
  var prog=gl.createProgram();gl.attachShader(prog,shader(gl,gl.VERTEX_SHADER,VS));
  gl.attachShader(prog,shader(gl,gl.FRAGMENT_SHADER,FS));gl.linkProgram(prog);
  if(!gl.getProgramParameter(prog,gl.LINK_STATUS))throw new Error("link: "+gl.getProgramInfoLog(prog));
  gl.useProgram(prog);
  var A={p:gl.getAttribLocation(prog,"p"),nn:gl.getAttribLocation(prog,"nn"),c:gl.getAttribLocation(prog,"c"),uv:gl.getAttribLocation(prog,"uv")};
  var U={};["mvp","mv","ps","lit","useTex","alpha","tex"].forEach(function(k){U[k]=gl.getUniformLocation(prog,k);});
  function buf(target,data){var b=gl.createBuffer();gl.bindBuffer(target,b);gl.bufferData(target,data,gl.STATIC_DRAW);return b;}
  function field(s){return s.charAt(0)==="@"?scene.shared[s.slice(1)]:s;}
  function normals(P,I,n){var N=new Float32Array(n*3);
    for(var t=0;t<I.length;t+=3){var a=3*I[t],b=3*I[t+1],c=3*I[t+2];
      var ux=P[b]-P[a],uy=P[b+1]-P[a+1],uz=P[b+2]-P[a+2],vx=P[c]-P[a],vy=P[c+1]-P[a+1],vz=P[c+2]-P[a+2];
      var nx=uy*vz-uz*vy,ny=uz*vx-ux*vz,nz=ux*vy-uy*vx;
      N[a]+=nx;N[a+1]+=ny;N[a+2]+=nz;N[b]+=nx;N[b+1]+=ny;N[b+2]+=nz;N[c]+=nx;N[c+1]+=ny;N[c+2]+=nz;}
    for(var q=0;q<3*n;q+=3){var l=Math.sqrt(N[q]*N[q]+N[q+1]*N[q+1]+N[q+2]*N[q+2])||1;N[q]/=l;N[q+1]/=l;N[q+2]/=l;}
    return N;}
  function upload(o){
    var P=b64(o.positions,Float32Array),n=o.n,col,I=o.indices?b64(field(o.indices),Uint32Array):null;
    if(o.colors){var cc=b64(o.colors,Uint8Array);col=new Float32Array(n*3);for(var i=0;i<n*3;i++)col[i]=cc[i]/255;}
    else{col=new Float32Array(n*3);for(var j=0;j<n;j++){col[3*j]=o.color[0];col[3*j+1]=o.color[1];col[3*j+2]=o.color[2];}}
    var g={o:o,pos:buf(gl.ARRAY_BUFFER,P),col:buf(gl.ARRAY_BUFFER,col),
      nrm:buf(gl.ARRAY_BUFFER,(o.mode==="triangles"&&I)?normals(P,I,n):new Float32Array(n*3)),
      uv:buf(gl.ARRAY_BUFFER,o.uv?b64(o.uv,Float32Array):new Float32Array(n*2)),count:n,idx:null,tex:null};
    if(I){
      if(!u32){var m=0;for(var k=0;k<I.length;k++)m=Math.max(m,I[k]);if(m>65535)throw new Error("mesh too large without OES_element_index_uint");I=new Uint16Array(I);}
      g.idx=buf(gl.ELEMENT_ARRAY_BUFFER,I);g.count=I.length;g.itype=(I instanceof Uint32Array)?gl.UNSIGNED_INT:gl.UNSIGNED_SHORT;}
    if(o.texture){g.tex=gl.createTexture();gl.bindTexture(gl.TEXTURE_2D,g.tex);
      gl.texImage2D(gl.TEXTURE_2D,0,gl.RGBA,1,1,0,gl.RGBA,gl.UNSIGNED_BYTE,new Uint8Array([128,128,128,255]));
      var im=new Image();im.onload=function(){gl.bindTexture(gl.TEXTURE_2D,g.tex);
        gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL,true);gl.texImage2D(gl.TEXTURE_2D,0,gl.RGBA,gl.RGBA,gl.UNSIGNED_BYTE,im);
        gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL,false);
        gl.texParameteri(gl.TEXTURE_2D,gl.TEXTURE_MIN_FILTER,gl.LINEAR);gl.texParameteri(gl.TEXTURE_2D,gl.TEXTURE_WRAP_S,gl.CLAMP_TO_EDGE);
        gl.texParameteri(gl.TEXTURE_2D,gl.TEXTURE_WRAP_T,gl.CLAMP_TO_EDGE);draw();};im.src=o.texture;}
    return g;}
  var statics=scene.objects.map(upload);
  var frames=(scene.frames||[]).map(function(f){return f.objects.map(upload);});
  var cur=Math.min(scene.start||0,Math.max(frames.length-1,0)),objs=statics.concat(frames.length?frames[cur]:[]);
  var cam=scene.camera,home={e:cam.position.slice(),t:cam.focal.slice(),u:cam.up.slice()};
  var eye=home.e.slice(),tgt=home.t.slice(),up=home.u.slice();
  var dist0=Math.sqrt(dot(sub(eye,tgt),sub(eye,tgt)));
  function bind(loc,b,size){if(loc<0)return;gl.bindBuffer(gl.ARRAY_BUFFER,b);gl.enableVertexAttribArray(loc);gl.vertexAttribPointer(loc,size,gl.FLOAT,false,0,0);}
  var drawn=0;
  function draw(){
    var w=canvas.clientWidth||canvas.width,h=canvas.clientHeight||canvas.height,dpr=window.devicePixelRatio||1;
    if(canvas.width!==Math.round(w*dpr)||canvas.height!==Math.round(h*dpr)){canvas.width=Math.round(w*dpr);canvas.height=Math.round(h*dpr);}
    gl.viewport(0,0,canvas.width,canvas.height);var bg=scene.background;gl.clearColor(bg[0],bg[1],bg[2],1);
    gl.clear(gl.COLOR_BUFFER_BIT|gl.DEPTH_BUFFER_BIT);gl.enable(gl.DEPTH_TEST);
    var d=Math.sqrt(dot(sub(eye,tgt),sub(eye,tgt)));
    var mv=lookAt(eye,tgt,up),pr=persp(cam.viewAngle*Math.PI/180,canvas.width/Math.max(1,canvas.height),d/100,d*20);
    gl.uniformMatrix4fv(U.mvp,false,new Float32Array(mul(pr,mv)));gl.uniformMatrix4fv(U.mv,false,new Float32Array(mv));
    gl.uniform1i(U.tex,0);drawn=0;
    [false,true].forEach(function(transparent){
      if(transparent){gl.enable(gl.BLEND);gl.blendFunc(gl.SRC_ALPHA,gl.ONE_MINUS_SRC_ALPHA);gl.depthMask(false);}
      else{gl.disable(gl.BLEND);gl.depthMask(true);}
      objs.forEach(function(g){var o=g.o;if((o.opacity<0.999)!==transparent)return;
        bind(A.p,g.pos,3);bind(A.c,g.col,3);bind(A.nn,g.nrm,3);bind(A.uv,g.uv,2);
        gl.uniform1f(U.alpha,o.opacity);gl.uniform1f(U.lit,(o.lighting&&o.mode==="triangles")?1:0);
        gl.uniform1f(U.ps,Math.max(1,o.pointSize)*dpr);gl.uniform1f(U.useTex,g.tex?1:0);
        gl.activeTexture(gl.TEXTURE0);gl.bindTexture(gl.TEXTURE_2D,g.tex);
        var mode=o.mode==="triangles"?gl.TRIANGLES:o.mode==="lines"?gl.LINES:gl.POINTS;
        if(g.idx&&mode!==gl.POINTS){gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER,g.idx);gl.drawElements(mode,g.count,g.itype,0);}
        else gl.drawArrays(gl.POINTS,0,o.n);
        drawn++;});});
    gl.depthMask(true);
    var err=gl.getError();if(err!==gl.NO_ERROR)throw new Error("WebGL error "+err);
    canvas.setAttribute("data-drawn",String(drawn));
  }
  var drag=null;
  canvas.addEventListener("pointerdown",function(e){drag={x:e.clientX,y:e.clientY,pan:e.shiftKey||e.button!==0};canvas.setPointerCapture(e.pointerId);});
  canvas.addEventListener("pointerup",function(){drag=null;});
  canvas.addEventListener("pointermove",function(e){if(!drag)return;var dx=e.clientX-drag.x,dy=e.clientY-drag.y;drag.x=e.clientX;drag.y=e.clientY;
    var f=sub(tgt,eye),d=Math.sqrt(dot(f,f)),r=nrm(crs(f,up)),u=nrm(crs(r,f));
    if(drag.pan){var s=d*0.0015;var m=add(scl(r,-dx*s),scl(u,dy*s));eye=add(eye,m);tgt=add(tgt,m);}
    else{var v=sub(eye,tgt);v=rot(v,[0,1,0],-dx*0.008);var r2=nrm(crs(sub(tgt,add(tgt,v)),[0,1,0]));
      var v2=rot(v,r2,-dy*0.008);if(Math.abs(dot(nrm(v2),[0,1,0]))<0.98)v=v2;eye=add(tgt,v);up=[0,1,0];}
    draw();});
  canvas.addEventListener("wheel",function(e){e.preventDefault();var v=sub(eye,tgt);eye=add(tgt,scl(v,Math.exp(e.deltaY*0.001)));draw();},{passive:false});
  canvas.addEventListener("dblclick",function(){eye=home.e.slice();tgt=home.t.slice();up=home.u.slice();draw();});
  window.addEventListener("resize",draw);
  function setFrame(k){if(!frames.length)return;cur=Math.max(0,Math.min(frames.length-1,k|0));
    objs=statics.concat(frames[cur]);draw();return scene.frames[cur];}
  draw();return {draw:draw,setFrame:setFrame,nFrames:frames.length};
};
})();
"""  # noqa: E501  (inline script and style)


def _color_bar_html(bar: dict) -> str:
    stops = ",".join(f"rgb({r},{g},{b})" for r, g, b in reversed(bar["colors"]))
    return (f'<div class="bs-bar"><span class="t">{html.escape(bar["title"])}</span>'
            f'<div class="grad" style="background:linear-gradient({stops})"></div>'
            f'<span class="hi">{bar["max"]:.1f}</span><span class="lo">{bar["min"]:.1f}</span></div>')


def share_repeated_indices(payload: dict) -> dict:
    """Store each distinct index array once (meshes of one topology: a body line-up, a session's frames).

    Repeats become ``"@k"`` references into ``payload["shared"]``; returns a new dict.
    """
    shared: dict[str, str] = {}
    seen: dict[str, str] = {}

    def share(obj: dict) -> dict:
        idx = obj.get("indices")
        if idx is None or len(idx) < 4096:
            return obj
        if idx not in seen:
            seen[idx] = str(len(seen))
            shared[seen[idx]] = idx
        return {**obj, "indices": "@" + seen[idx]}

    out = {**payload, "objects": [share(o) for o in payload.get("objects", [])]}
    if payload.get("frames"):
        out["frames"] = [{**f, "objects": [share(o) for o in f["objects"]]} for f in payload["frames"]]
    out["shared"] = shared
    return out


def viewer_fragment(payload: dict, element_id: str) -> str:
    """HTML for one 3D view (needs :data:`VIEWER_CSS` and :data:`VIEWER_JS` once on the page)."""
    if not element_id.isidentifier():
        raise InputError(f"view id {element_id!r} must be an identifier")
    data = json.dumps(share_repeated_indices(payload), separators=(",", ":")).replace("</", "<\\/")
    bars = "".join(_color_bar_html(b) for b in payload.get("colorBars", []))
    frames = payload.get("frames") or []
    slider = ""
    if len(frames) > 1:
        k0 = int(payload.get("start", 0))
        slider = (f'<div class="bs-frames">frame <input type="range" id="{element_id}-frame" min="0" '
                  f'max="{len(frames) - 1}" value="{k0}" step="1"> <span id="{element_id}-frame-label">'
                  f'{frames[k0]["id"]}</span></div>')
    return (f'<div class="bs-view"><canvas id="{element_id}" width="1024" height="768"></canvas>{bars}'
            '<div class="bs-help">drag: rotate, shift+drag: pan, wheel: zoom, double-click: reset</div></div>\n'
            f"{slider}"
            f'<script type="application/json" id="{element_id}-data">{data}</script>\n'
            f"<script>bodystudioMount({json.dumps(element_id)});</script>\n")


# Records the page's state (and any error, including the browser's own) for headless checks.
STATUS_JS = r"""
window.bodystudioErrors=[];
function bodystudioStatus(){var b=document.body;if(!b)return;
  b.setAttribute("data-viewer-errors",String(window.bodystudioErrors.length));
  b.setAttribute("data-viewer-status",window.bodystudioErrors.length?("error: "+window.bodystudioErrors.join(" | ")):"ok");}
window.addEventListener("error",function(e){window.bodystudioErrors.push(String(e.message||e));bodystudioStatus();});
function bodystudioMount(id){try{var c=document.getElementById(id);
  var scene=JSON.parse(document.getElementById(id+"-data").textContent);
  var view=bodystudioView(c,scene);var s=document.getElementById(id+"-frame");
  if(s)s.addEventListener("input",function(){var f=view.setFrame(Number(s.value));
    document.getElementById(id+"-frame-label").textContent=String(f.id);
    var bars=c.parentNode.querySelectorAll(".bs-bar");(f.colorBars||[]).forEach(function(b,i){if(!bars[i])return;
      bars[i].querySelector(".hi").textContent=b.max.toFixed(1);bars[i].querySelector(".lo").textContent=b.min.toFixed(1);});
    c.setAttribute("data-frame",String(f.id));});
  var n=Number(document.body.getAttribute("data-views-drawn")||0)+1;document.body.setAttribute("data-views-drawn",String(n));}
  catch(e){window.bodystudioErrors.push(id+": "+e.message);var m=document.createElement("div");m.className="bs-msg";
    m.textContent="3D view unavailable: "+e.message;var c2=document.getElementById(id);if(c2&&c2.parentNode)c2.parentNode.appendChild(m);}
  bodystudioStatus();}
"""  # noqa: E501  (inline script and style)


def page_head(title: str, extra_css: str = "") -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title>\n<style>{VIEWER_CSS}{extra_css}</style>\n"
            f"<script>{STATUS_JS}{VIEWER_JS}</script></head>\n")


def scene_html(plotter, title: str = "bodystudio view", payload: dict | None = None) -> str:
    """A complete standalone page showing the plotter's scene (or a prepared ``payload``)."""
    payload = scene_payload(plotter) if payload is None else payload
    css = "body{margin:0;background:#1d1e23;color:#eee;font-family:sans-serif}h1{font-size:16px;margin:8px 12px}"
    return (page_head(title, css) + f"<body><h1>{html.escape(title)}</h1>\n" + viewer_fragment(payload, "view3d")
            + "</body></html>\n")


def save_scene_html(plotter, path: str | Path, title: str = "bodystudio view", payload: dict | None = None) -> Path:
    """Write the standalone HTML page atomically (``.html``); ``payload`` replaces the plotter's scene."""
    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"{path}: HTML export needs a path ending in .html")
    text = scene_html(plotter, title, payload)
    with atomic_write(path, "w") as f:
        f.write(text)
    log.info("wrote %s (%.1f MB)", path, len(text) / 1e6)
    return path
