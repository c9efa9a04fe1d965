import sys, collections, statistics as st
log=sys.argv[1]
C=collections.defaultdict(list)
for l in open(log):
    p=l.split()
    if p and p[0]=='DIAGC': C[(int(p[1]),float(p[2]))].append(p[3:])
def q(xs,f): xs=sorted(xs); return xs[int(f*(len(xs)-1))] if xs else float('nan')
for key in sorted(C):
    rows=C[key]
    R=[]
    for r in rows:
        cand,guard,bl,bu,md,mdl,mdr,mdu,br,cn,cnew,cg=int(r[0]),float(r[1]),float(r[2]),int(r[3]),int(r[4]),float(r[5]),float(r[6]),int(r[7]),float(r[8]),float(r[9]),int(r[10]),float(r[11])
        R.append(dict(cand=cand,guard=guard,bl=bl,bu=bu,md=md,mdl=mdl,mdr=mdr,mdu=mdu,br=br,cn=cn,cnew=cnew,cg=cg))
    print(key)
    for nm,xs in [('guard',[r['guard'] for r in R]),('md loss/guard',[-r['mdl']/r['guard'] if r['guard']>0 else 0 for r in R]),
                  ('md unique cells',[r['mdu'] for r in R]),('md red',[r['mdr'] for r in R]),('chosen red',[r['br'] for r in R]),
                  ('chosen loss',[-r['bl'] for r in R]),('chosen unique',[r['bu'] for r in R]),('cand nearest',[r['cn'] for r in R]),
                  ('cand new cells',[r['cnew'] for r in R]),('cand gross gain',[r['cg'] for r in R])]:
        print('  %-16s p10 %.3f p50 %.3f p90 %.3f'%(nm,q(xs,.1),q(xs,.5),q(xs,.9)))
    print('  md has unique cells:',sum(r['mdu']>0 for r in R),'/',len(R))
