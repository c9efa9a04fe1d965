import json,glob,os
import os.path
R=os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
def load(path):
    out={}
    for l in open(path):
        d=json.loads(l)
        if d.get('bench')=='product_eval' and d['method']=='lumigraph_product':
            out[d['fold']]=d['quality']
        if d.get('bench')=='product_eval_ingest':
            out[('ing',d['fold'])]=d
    return out
rows=[]
for S in (50,100,200):
    lum=load(f'{R}/s16/product_eval_store{S}_folds01_time_default.jsonl')
    cells={'lumigraph (session 16 run)':lum}
    for P in ('every_n','every_n_online','min_distance'):
        f=f'{R}/s17/product_eval_store{S}_{P}.jsonl'
        if os.path.exists(f): cells[P]=load(f)
    for name,c in cells.items():
        if 0 not in c: continue
        q0=c[0]; q1=c.get(1)
        acc=[c.get(('ing',f),{}).get('planning_accepted') for f in (0,1)]
        def fmt(k,nd=4): return ' / '.join(('%.*f'%(nd,q[k])) if q else '–' for q in (q0,q1))
        dl=''
        if name!='lumigraph (session 16 run)' and 0 in lum:
            ds=[lum[f]['ssim']-c[f]['ssim'] for f in (0,1) if f in c]
            dp=[lum[f]['psnr']-c[f]['psnr'] for f in (0,1) if f in c]
            dl='%+.4f / %+.2f dB'%(sum(ds)/len(ds), sum(dp)/len(dp))
        rows.append(f"| {S} | {name} | {fmt('ssim')} | {fmt('psnr',2)} | {fmt('ssim_unfilled')} | {fmt('coverage',3)} | {dl} | {acc[0] or '–'} / {acc[1] or '–'} |")
print('| store | policy | SSIM folds 0 / 1 | PSNR dB | unfilled SSIM | coverage | lumigraph − policy (mean SSIM / PSNR) | frames accepted |')
print('|---|---|---|---|---|---|---|---|')
print('\n'.join(rows))
