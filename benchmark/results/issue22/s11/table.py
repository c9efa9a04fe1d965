import json,glob,collections,statistics as st,sys
D=collections.defaultdict(dict)
for f in glob.glob('/tmp/s11/sw1_*_s*.jsonl')+glob.glob('/tmp/s11/dgua_*_s*.jsonl')+glob.glob('/tmp/s11/bl_*_s*.jsonl')+glob.glob('/tmp/s11/mpr_*_s*.jsonl'):
  for l in open(f):
    r=json.loads(l); c=r['config']
    name=c['policy']+('' if r['tag']=='main' else ':'+r['tag'])
    seed=f.split('_s')[-1].split('.')[0]; stream=r['dataset'].split('/seed')[0].split('/')[1]
    D[(stream,r['test_poses'],name,c['store'])][seed]=r['quality']['mssim']
ORDER=[('online','old default (frozen-τ guard)'),('online:dgua=8','new default (unique guard after 8 frames/view)'),('online:dgu=1','unique guard from the start'),('online:dgr=0+dg=1e9','pure dispersion (no guard)'),('online:dgr=0+dg=1e9+mpr=1.57','pure dispersion, mpr 1.57'),('min_distance','min-distance'),('every_n_online','progressive every-N'),('reservoir','reservoir'),('keyframe','keyframes'),('every_n','every-N (oracle)')]
ref=sys.argv[1] if len(sys.argv)>1 else 'min_distance'
new=sys.argv[2] if len(sys.argv)>2 else 'online:dgua=8'
stores=[50,100,200]
for stream in ['drone','handheld']:
  for poses in ['near','scene']:
    print(f'\n| apartment {stream}, {"near" if poses=="near" else "scene-wide"} (3 seeds) | 50 | 100 | 200 |')
    print('|---|---|---|---|')
    for n,label in ORDER:
      cells=[]
      for s in stores:
        v=D.get((stream,poses,n,s))
        if not v: cells.append('–'); continue
        vals=list(v.values()); m=st.mean(vals); sd=st.stdev(vals) if len(vals)>1 else 0
        cell='%.3f ± %.3f'%(m,sd)
        nv=D.get((stream,poses,new,s))
        if nv and n!=new:
          d=[nv[x]-v[x] for x in nv if x in v]; w=sum(x>0 for x in d); L=sum(x<0 for x in d)
          cell+=' (%+.3f, %d/%d)'%(st.mean(d),w,len(d))
        cells.append(cell)
      print(f'| {label} | '+' | '.join(cells)+' |')
