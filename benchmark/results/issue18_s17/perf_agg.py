import sys,re,collections
# perf script output -> for samples whose chain contains ROOT: counts by leaf and by child-of-root
root=sys.argv[1]; f=sys.argv[2]; top=int(sys.argv[3]) if len(sys.argv)>3 else 25
txt=open(f,errors='replace').read().split('\n\n')
leaf=collections.Counter(); child=collections.Counter(); n=0; total=0
def sym(line):
    s=line.strip().split(None,1)
    if len(s)<2: return '?'
    s=s[1]; s=re.sub(r'\+0x[0-9a-f]+','',s); s=re.sub(r'\s*\(.*\)$','',s)
    s=re.sub(r'\(exo::[^()]*(\([^()]*\))*[^()]*\)','(..)',s)
    return s[:110]
for blk in txt:
    lines=[l for l in blk.split('\n') if l.strip()]
    if len(lines)<2: continue
    total+=1
    frames=[sym(l) for l in lines[1:]]
    idx=[i for i,s in enumerate(frames) if root in s]
    if not idx: continue
    n+=1
    i=idx[-1]  # outermost occurrence
    leaf[frames[0]]+=1
    child[frames[i-1] if i>0 else '(self)']+=1
print('samples total',total,'under',root,n)
print('-- by direct child of root')
for k,v in child.most_common(top): print('%6.1f%% %s'%(100*v/n,k))
print('-- by leaf')
for k,v in leaf.most_common(top): print('%6.1f%% %s'%(100*v/n,k))
