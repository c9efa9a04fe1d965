import sys, math, collections, json
log=sys.argv[1]
F={}; C=collections.defaultdict(list); A=collections.defaultdict(list); S=collections.defaultdict(lambda: collections.defaultdict(list))
for l in open(log):
    p=l.split()
    if not p or not p[0].startswith('DIAG'): continue
    if p[0]=='DIAGF': F[int(p[1])]=tuple(map(float,p[2:8]))
    elif p[0]=='DIAGC': C[(int(p[1]),float(p[2]))].append(p[3:])
    elif p[0]=='DIAGA': A[(int(p[1]),float(p[2]))].append((int(p[3]),int(p[4]),float(p[5])))
    elif p[0]=='DIAGS': S[(int(p[1]),float(p[2]))][int(p[3])].append(p[4:])
ids=sorted(F)
# yaw rate per frame (deg/frame) and speed m/frame
def yaw(f): return math.atan2(f[4],f[3])
yr={}; sp={}
for i in ids:
    j=i-1 if i-1 in F else i+1
    if j not in F: yr[i]=0; sp[i]=0; continue
    d=yaw(F[i])-yaw(F[j]); d=(d+math.pi)%(2*math.pi)-math.pi
    yr[i]=abs(math.degrees(d))*30; sp[i]=math.dist(F[i][:3],F[j][:3])*30
pan=lambda i: yr.get(i,0)>60 and sp.get(i,0)<0.2
still=lambda i: yr.get(i,0)<1 and sp.get(i,0)<0.01
print('frames',len(ids),'pan frames',sum(pan(i) for i in ids),'still',sum(still(i) for i in ids))
for key in sorted(C):
    rows=C[key]; n=len(rows)
    blocked=[r for r in rows if r[0]!=r[4] and True]
    # r: cand guard best_loss b_unique md_id md_loss md_red md_unique best_red cn cnew cgain x z
    # wait indices
    blk=[r for r in rows if r[4]!=None]
    nb=0; mdpan=0; mdu=[]; red_ratio=[]
    for r in rows:
        cand,guard,bl,bu,md,mdl,mdr,mdu_,br,cn,cnew,cg=int(r[0]),float(r[1]),float(r[2]),int(r[3]),int(r[4]),float(r[5]),float(r[6]),int(r[7]),float(r[8]),float(r[9]),int(r[10]),float(r[11])
        if md!=cand and mdl < -guard:
            nb+=1; mdpan+=pan(md); mdu.append(mdu_); red_ratio.append((mdr,br))
    acc=A[key]; ng=sum(1 for a in acc if a[1]==1); ns=sum(1 for a in acc if a[1]==2)
    print(key,'full considers',n,'md victim guarded',nb, f'({100*nb/max(1,n):.0f}%)','of which pan frames',mdpan,
          'md unique cells median',sorted(mdu)[len(mdu)//2] if mdu else None,
          'accepted gain>thr',ng,'spread',ns)
for key in sorted(S):
    last=max(S[key]); rows=S[key][last]
    vids=sorted(int(r[0]) for r in rows)
    gaps=[b-a for a,b in zip(vids,vids[1:])]
    short=sum(g<=3 for g in gaps)
    npan=sum(pan(v) for v in vids); nst=sum(still(v) for v in vids)
    guard=None
    for r in rows:
        pass
    mt=float(rows[0][6])
    g=key[1]*mt if key[1]>0 else None
    losses=[float(r[1]) for r in rows]; uniq=[int(r[3]) for r in rows]
    nguarded=sum(1 for L in losses if g and L< -g)
    d1=sorted(float(r[2]) for r in rows)
    print(key,'@',last,'views',len(vids),'gaps<=3',short,'pan views',npan,'still',nst,'guarded',nguarded,
          'unique>0',sum(u>0 for u in uniq),'d1 median %.3f p10 %.3f'%(d1[len(d1)//2],d1[len(d1)//10]))
