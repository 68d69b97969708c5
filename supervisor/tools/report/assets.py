"""The page's style and script, inlined into every report (no network: the file is
attached to incident tickets and opened anywhere; docs/reference/commands.md, "report")."""

CSS = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",sans-serif;margin:0 auto;max-width:1250px;
 padding:0 18px 60px;color:#1d232a;background:#fff}
h1{font-size:22px;margin:18px 0 4px}h2{font-size:18px;margin:28px 0 8px;border-bottom:1px solid #ccd}
h3{font-size:15px;margin:18px 0 6px}code,pre,.mono{font-family:ui-monospace,Menlo,Consolas,monospace;
 font-size:12.5px}pre{background:#f5f6f8;padding:8px;overflow:auto;margin:4px 0}
table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #d4d8de;padding:3px 7px;
 vertical-align:top;text-align:left}th{background:#f0f2f5}.meta td:first-child{font-weight:600}
.integrity{padding:10px 14px;border-radius:6px;margin:12px 0;font-weight:600}
.integrity.ok{background:#e5f5e8;border:1px solid #7bbf88}
.integrity.broken{background:#fde8e8;border:1px solid #d66}
.note{color:#7a5a00;background:#fff8e0;padding:4px 8px;margin:3px 0;border-left:3px solid #e0b000}
.muted{color:#667}.num{text-align:right;font-variant-numeric:tabular-nums}
#timeline{border:1px solid #d4d8de;background:#fff;cursor:crosshair;user-select:none}
#timeline .lane-event{fill:#f7f8fa}#timeline .lane-input{fill:#fbfcfd}
#timeline .lane-label{font-size:11px;text-anchor:end;fill:#333}
#timeline .range{font-size:9px;fill:#889}
#timeline .line{fill:none;stroke:#2b6cb0;stroke-width:1.4;vector-effect:non-scaling-stroke}
#timeline .band{fill:#5a8fd0;opacity:.75}#timeline .stale{fill:#f0a030;opacity:.35}
#timeline .mk{stroke-width:2.5;vector-effect:non-scaling-stroke}
#timeline .mk.violation{stroke:#d0202a;stroke-width:3}
#timeline .vline{stroke:#d0202a;stroke-width:1;opacity:.25;vector-effect:non-scaling-stroke}
#timeline .mk.mitigation.ok{stroke:#1f8a3a}#timeline .mk.mitigation.failed{stroke:#7a0010}
#timeline .mk.mitigation.dry{stroke-dasharray:2 2}
#timeline .mk.reset{stroke:#3060c0}#timeline .mk.supervisor.major{stroke:#7040a0;stroke-width:3}
#timeline .mk.supervisor.minor{stroke:#99a}#timeline .mk.supervisor.input{stroke:#e08a00}
#timeline .mk.prediction{stroke:#e06000;stroke-width:3}#timeline .mk.prediction.expired{stroke:#a0a0a0}
#timeline .lead{fill:#f4b07a;opacity:.7}
#timeline .line.margin{stroke:#8a3ab9}
#timeline .zero{stroke:#556;stroke-width:1;stroke-dasharray:4 3;vector-effect:non-scaling-stroke}
#timeline #cursor{stroke:#000;stroke-width:1;opacity:.4;vector-effect:non-scaling-stroke}
#timeline #axis text{font-size:10px;text-anchor:middle;fill:#445}#timeline #axis line{stroke:#445}
#tip{position:absolute;background:#fffffff0;border:1px solid #99a;padding:4px 7px;
 font:12px ui-monospace,Menlo,Consolas,monospace;white-space:pre;pointer-events:none;z-index:5}
.legend span{display:inline-block;margin-right:14px}.legend i{display:inline-block;width:12px;
 height:10px;margin-right:4px;vertical-align:middle}
.why{border:1px solid #d4d8de;border-radius:6px;padding:6px 12px;margin:10px 0}
.why .sentence{font-weight:600}.why-tree td.v{text-align:center;min-width:34px}
.why-tree td.f{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:12px;white-space:pre}
.why-tree .true{background:#e3f4e6}.why-tree .false{background:#fbe1e1}
.why-tree td.blame{outline:2px solid #d0202a;outline-offset:-2px;font-weight:700}
.why-tree tr.blame td.f{font-weight:700}.why-tree th.now{background:#fbe1e1}
"""

# Zoom (wheel: around the cursor; drag: pan; double-click: back), the time axis and
# the inputs' values under the cursor. The SVG is drawn by timeline.py.
JS = """
(function(){
var svg=document.getElementById('timeline');if(!svg)return;
var W=+svg.dataset.width,L=+svg.dataset.label,NS='http://www.w3.org/2000/svg';
var data=JSON.parse(document.getElementById('timeline-data').textContent);
var zoom=document.getElementById('zoom'),axis=document.getElementById('axis'),
 cur=document.getElementById('cursor'),tip=document.getElementById('tip');
var k=1,tx=0,drag=null;
function px(e){var p=svg.createSVGPoint();p.x=e.clientX;p.y=e.clientY;
 return p.matrixTransform(svg.getScreenCTM().inverse()).x-L;}
function sec(x){return (x-tx)/k/W*data.span;}
function el(n,a){var e=document.createElementNS(NS,n);for(var q in a)e.setAttribute(q,a[q]);return e;}
function draw(){k=Math.min(Math.max(k,1),1e7);tx=Math.min(0,Math.max(W-W*k,tx));
 zoom.setAttribute('transform','translate('+tx+',0) scale('+k+',1)');
 while(axis.firstChild)axis.removeChild(axis.firstChild);
 var a=sec(0),b=sec(W),raw=(b-a)/8,p=Math.pow(10,Math.floor(Math.log10(raw))),st=p;
 [1,2,5,10].some(function(m){st=m*p;return st>=raw;});
 for(var i=Math.ceil(a/st);i*st<=b;i++){var x=i*st/data.span*W*k+tx;
  axis.appendChild(el('line',{x1:x,x2:x,y1:0,y2:4}));
  var t=el('text',{x:x,y:16});t.textContent=(+(i*st).toPrecision(10))+' s';axis.appendChild(t);}}
function at(s,t){var lo=0,hi=s.t.length-1;if(hi<0||s.t[0]>t)return '-';
 while(lo<hi){var m=(lo+hi+1)>>1;if(s.t[m]<=t)lo=m;else hi=m-1;}return s.v[lo];}
function hover(x,e){if(x<0||x>W){tip.hidden=true;return;}
 cur.setAttribute('x1',x);cur.setAttribute('x2',x);
 var t=sec(x),rows=['t = '+t.toFixed(3)+' s'];
 data.series.forEach(function(s){rows.push(s.name+' = '+at(s,t));});
 tip.textContent=rows.join('\\n');tip.hidden=false;
 tip.style.left=(e.pageX+14)+'px';tip.style.top=(e.pageY+14)+'px';}
svg.addEventListener('wheel',function(e){e.preventDefault();var x=px(e),
 k2=Math.min(Math.max(k*Math.exp(-e.deltaY*0.002),1),1e7);tx=x-(x-tx)*k2/k;k=k2;draw();hover(x,e);},
 {passive:false});
svg.addEventListener('mousedown',function(e){drag={x:px(e),tx:tx};});
window.addEventListener('mouseup',function(){drag=null;});
svg.addEventListener('mousemove',function(e){var x=px(e);if(drag){tx=drag.tx+x-drag.x;draw();}
 hover(x,e);});
svg.addEventListener('mouseleave',function(){tip.hidden=true;});
svg.addEventListener('dblclick',function(){k=1;tx=0;draw();});
draw();
})();
"""
