// The plain 3-D step of geodem's numba backend (move + owner pass + finish: translation only,
// no rotation, no contact dashpot) written in C, to measure how far numba's code is from a C
// compiler's on the same algorithm and data (docs/performance.md, "The same step in C").
// Not part of geodem: tests/perf/compare_c_step.py builds it with gcc and times it against
// the numba kernels on the bench specimen (-DOWNER_SIMD: the row loop vectorised). Semantics follow geodem/backends/step_bodies.py
// (move_body, owner_body, finish_body) and geodem/core/law.py (contact).
#include <math.h>
#include <stdint.h>
#include <stddef.h>
#ifndef NBR_T
#define NBR_T int32_t
#endif
#ifndef CS_T
#define CS_T int32_t
#endif
#define BONDED 1
#define NB 6

static inline double series(double a, double b){ double s=a+b; return s>0.0? a*b/s : 0.0; }
static inline double spring_energy(double f2, double k){ return k>0.0? 0.5*f2/k : 0.0; }

static void move(int n, double*restrict x, const double*restrict v, const double*restrict a,
                 double*restrict dx, const double*restrict fr, const double*restrict fload,
                 const double*restrict m, const double*restrict eta,
                 double*restrict q_visc, double*restrict w_ext, double dt){
    #pragma omp for schedule(static)
    for (int i=0;i<n;i++){
        double qv=0, we=0;
        for(int d=0; d<3; d++){
            size_t q=3*(size_t)i+d; double ddx;
            if (fr[q]!=0.0){ ddx = dt*v[q]+0.5*dt*dt*a[q]; qv += 0.5*eta[i]*v[q]*ddx; we += fload[q]*ddx; }
            else { ddx = dt*v[q]; we -= 0.5*m[i]*a[q]*ddx; }
            dx[q]=ddx; x[q]+=ddx;
        }
        q_visc[i]+=qv; w_ext[i]+=we;
    }
}

// Warm the caches: the partners of element i + ahead and the rows of element i + 4 ahead.
static inline void prefetch_ahead(int i, int hi, int n, int W, const double*x, const double*dx,
    const double*props, const NBR_T*nbr, const int32_t*ostart, const CS_T*cstate,
    const double*fs, const float*brate, const double*buf, const int32_t*cstart,
    const int32_t*spill, int ahead){
    if (ahead>0 && i+ahead<hi){
        int ii=i+ahead; int c=cstart[ii];
        for(int k=ostart[ii];k<W;k++){ int j=nbr[(size_t)ii*W+k]; if(j<0)break;
            __builtin_prefetch(x+3*(size_t)j); __builtin_prefetch(dx+3*(size_t)j);
            __builtin_prefetch(props+8*(size_t)j);
            if (j<hi) __builtin_prefetch(buf+NB*(size_t)j); else {__builtin_prefetch(buf+NB*(size_t)(n+spill[c])); c++;}
        }
    }
    if (ahead>0 && i+4*ahead<hi){
        size_t ii=i+4*ahead;
        __builtin_prefetch(nbr+ii*W); __builtin_prefetch(cstate+ii*W); __builtin_prefetch(brate+ii*W);
        for(int off=0; off<W*3*8; off+=64) __builtin_prefetch((char*)(fs+ii*W*3)+off);
    }
}

// What one contact e = (i, j) of a row reads: its state, the branch and relative displacement,
// the stored spring, the partner's parameters and the bond rate (both row loops below).
#define CONTACT_LOADS \
    CS_T cs=cstate[e]; \
    const double*pj=props+8*(size_t)j; \
    double bx=x[3*j]-xi0, by=x[3*j+1]-xi1, bz=x[3*j+2]-xi2; \
    double rx=dx[3*j]-di0, ry=dx[3*j+1]-di1, rz=dx[3*j+2]-di2; \
    double sx=fs[3*e], sy=fs[3*e+1], sz=fs[3*e+2]; \
    double rj=pj[0],knj=pj[1],ksj=pj[2],xbj=pj[3],fs0j=pj[4],muj=pj[5]; \
    double rate=brate[e];

// The law's first part, alike in both loops: the normal, the overlap, the series stiffnesses,
// the stored spring rotated onto the tangent plane (its lost energy eqf) and the trial spring.
#define CONTACT_TRIAL \
    double dist=sqrt(bx*bx+by*by+bz*bz), inv=1.0/dist; \
    double nx=bx*inv, ny=by*inv, nz=bz*inv; \
    double xn=dist-(ri+rj); \
    double kn=series(kni,knj), ks=series(ksi,ksj); \
    double hks= ks>0.0? 0.5/ks : 0.0; \
    double p=nx*sx+ny*sy+nz*sz; \
    sx-=p*nx; sy-=p*ny; sz-=p*nz; \
    double eqf=p*p*hks; \
    double pr=nx*rx+ny*ry+nz*rz; \
    double ux=rx-pr*nx, uy=ry-pr*ny, uz=rz-pr*nz; \
    double tx=sx+ks*ux, ty=sy+ks*uy, tz=sz+ks*uz; \
    double tr2=tx*tx+ty*ty+tz*tz;

static void owner(int n, int W, int nslab, const double*restrict x, const double*restrict dx,
    const double*restrict props, const NBR_T*restrict nbr, const int32_t*restrict ostart,
    const int8_t*restrict mirror, CS_T*restrict cstate, double*restrict fs,
    const float*restrict brate, double*restrict buf, const int32_t*restrict cstart,
    const int32_t*restrict spill, CS_T code_t, CS_T code_s, int hertz, int ahead){
    #pragma omp for schedule(static)
    for (int t=0;t<nslab;t++){
        int lo = (int)((int64_t)t*n/nslab), hi=(int)((int64_t)(t+1)*n/nslab);
        for (int i=lo;i<hi;i++){
            prefetch_ahead(i, hi, n, W, x, dx, props, nbr, ostart, cstate, fs, brate, buf, cstart,
                           spill, ahead);
            const double xi0=x[3*i],xi1=x[3*i+1],xi2=x[3*i+2];
            const double di0=dx[3*i],di1=dx[3*i+1],di2=dx[3*i+2];
            const double*pi=props+8*(size_t)i;
            const double ri=pi[0],kni=pi[1],ksi=pi[2],xbi=pi[3],fs0i=pi[4],mui=pi[5];
            double f0=0,f1=0,f2=0,qn=0,qs=0,qf=0;
#ifdef OWNER_SIMD
            // The row loop vectorised (OpenMP SIMD): every branch of the law becomes a select, so
            // one AVX-512 instruction evaluates up to 8 owned contacts of a row; the partners' data
            // come in by gathers and the posts go out by scatters (a row's partners are distinct,
            // so the lanes never collide). Same results as the scalar loop up to round-off.
            const size_t row=(size_t)i*W;
            int k0=ostart[i], kend=k0, kc=W;
            while (kend<W && nbr[row+kend]>=0){ if (kc==W && nbr[row+kend]>=hi) kc=kend; kend++; }
            const int cbase=cstart[i]-kc;
            #pragma omp simd reduction(+:f0,f1,f2,qn,qs,qf)
            for (int k=k0; k<kend; k++){
                size_t e=row+k;
                int j=nbr[e];
                CONTACT_LOADS
                CONTACT_TRIAL
                double hkn= kn>0.0? 0.5/kn : 0.0, tu=tx*ux+ty*uy+tz*uz;
                double mu=fmin(mui,muj);
                double fnl;
                if (hertz){
                    double ei=kni/(M_PI*ri), ej=knj/(M_PI*rj), pen=fmax(-xn,0.0);
                    double se=ei+ej, sr=ri+rj;
                    fnl=-(4.0/3.0)*(ei*ej/se)*sqrt(ri*rj/sr)*pen*sqrt(pen);
                } else fnl=kn*xn;
                int bonded = cs==BONDED;
                double fnb=kn*xn;
                double fn0 = bonded? fnb : fnl;
                double bf=rate*fmin(kni*xbi,knj*xbj);
                int tbreak = bonded & (fnb>=bf);
                double fsmax=rate*fmin(fs0i,fs0j)-mu*fnb;
                int sfail = bonded & !tbreak & ((fsmax<0.0) | (tr2>fsmax*fsmax));
                int sfree = sfail & (fnb>=0.0);
                int open = !bonded & (xn>=0.0);
                double lim=-mu*fn0;
                int slide = (sfail & !sfree) | (!bonded & !open & (tr2>lim*lim));
                double scale=lim/sqrt(fmax(tr2,1e-300));
                int zero = tbreak | sfree | open;
                double m1 = zero? 0.0 : slide? scale : 1.0;
                double ox=tx*m1, oy=ty*m1, oz=tz*m1;
                double fn = zero? 0.0 : fn0;
                double ebreak=fnb*fnb*hkn+tr2*hks-0.5*(fnb*pr+tu);
                double eqn = tbreak? ebreak : 0.0;
                double eqs = sfree? ebreak : (sfail & !sfree)? (tr2-lim*lim)*hks-0.5*(1.0-scale)*tu : 0.0;
                eqf += open? (sx*sx+sy*sy+sz*sz)*hks
                     : (slide & !bonded)? ((sx+ox)*(tx-ox)+(sy+oy)*(ty-oy)+(sz+oz)*(tz-oz))*hks : 0.0;
                CS_T csn = tbreak? code_t : sfail? code_s : cs;
                fs[3*e]=ox; fs[3*e+1]=oy; fs[3*e+2]=oz;
                if (csn!=cs){ cstate[e]=csn; cstate[(size_t)j*W+mirror[e]]=csn; }
                double a0=fn*nx+ox, a1=fn*ny+oy, a2=fn*nz+oz;
                f0+=a0; f1+=a1; f2+=a2; qn+=eqn; qs+=eqs; qf+=eqf;
                size_t r = k<kc? (size_t)j : (size_t)n+spill[cbase+k];
                double*br=buf+NB*r;
                br[0]-=a0; br[1]-=a1; br[2]-=a2;
                br[3]+=0.5*eqf; br[4]+=0.5*eqn; br[5]+=0.5*eqs;
            }
#else
            int c=cstart[i];
            for (int k=ostart[i]; k<W; k++){
                size_t e=(size_t)i*W+k;
                int j=nbr[e]; if (j<0) break;
                CONTACT_LOADS
                // ---- the law
                CONTACT_TRIAL
                double eqn=0, eqs=0, mu=fmin(mui,muj), fn;
                double ox,oy,oz; CS_T csn=cs;
                if (cs==BONDED){
                    fn=kn*xn;
                    double bf=rate*fmin(kni*xbi,knj*xbj);
                    if (fn>=bf){
                        eqn=spring_energy(fn*fn,kn)+tr2*hks-0.5*(fn*pr+tx*ux+ty*uy+tz*uz);
                        fn=0; ox=oy=oz=0; csn=code_t;
                    } else {
                        double fsmax=rate*fmin(fs0i,fs0j)-mu*fn;
                        if (fsmax<0.0 || tr2>fsmax*fsmax){
                            if (fn>=0.0){
                                eqs=spring_energy(fn*fn,kn)+tr2*hks-0.5*(fn*pr+tx*ux+ty*uy+tz*uz);
                                fn=0; ox=oy=oz=0; csn=code_s;
                            } else {
                                double lim=-mu*fn, scale=lim/sqrt(tr2);
                                eqs=(tr2-lim*lim)*hks-0.5*(1.0-scale)*(tx*ux+ty*uy+tz*uz);
                                ox=tx*scale; oy=ty*scale; oz=tz*scale; csn=code_s;
                            }
                        } else { ox=tx; oy=ty; oz=tz; }
                    }
                } else if (xn>=0.0){
                    eqf+=(sx*sx+sy*sy+sz*sz)*hks; fn=0; ox=oy=oz=0;
                } else {
                    if (hertz){
                        double ei=kni/(M_PI*ri), ej=knj/(M_PI*rj);
                        fn=-(4.0/3.0)*series(ei,ej)*sqrt(series(ri,rj))*(-xn)*sqrt(-xn);
                    } else fn=kn*xn;
                    double lim=-mu*fn;
                    if (tr2>lim*lim){
                        double scale=lim/sqrt(tr2);
                        ox=tx*scale; oy=ty*scale; oz=tz*scale;
                        eqf+=((sx+ox)*(tx-ox)+(sy+oy)*(ty-oy)+(sz+oz)*(tz-oz))*hks;
                    } else { ox=tx; oy=ty; oz=tz; }
                }
                fs[3*e]=ox; fs[3*e+1]=oy; fs[3*e+2]=oz;
                if (csn!=cs){ cstate[e]=csn; cstate[(size_t)j*W+mirror[e]]=csn; }
                double a0=fn*nx+ox, a1=fn*ny+oy, a2=fn*nz+oz;
                f0+=a0; f1+=a1; f2+=a2; qn+=eqn; qs+=eqs; qf+=eqf;
                size_t r=j; if (j>=hi){ r=(size_t)n+spill[c]; c++; }
                double*br=buf+NB*r;
                br[0]-=a0; br[1]-=a1; br[2]-=a2;
                if (eqn!=0.0||eqs!=0.0){ br[4]+=0.5*eqn; br[5]+=0.5*eqs; }
                br[3]+=0.5*eqf;
            }
#endif
            double*bi=buf+NB*(size_t)i;
            bi[0]+=f0; bi[1]+=f1; bi[2]+=f2; bi[3]+=0.5*qf; bi[4]+=0.5*qn; bi[5]+=0.5*qs;
        }
    }
}



static void finish(int n, double*restrict v, double*restrict a, const double*restrict dx,
    const double*restrict fr, const double*restrict fload, const double*restrict m,
    const double*restrict eta, double*restrict buf, const int32_t*restrict inc_start,
    double*restrict q_visc, double*restrict q_bn, double*restrict q_bs, double*restrict q_f,
    double*restrict w_ext, double g0, double g1, double g2, double dt){
    #pragma omp for schedule(static)
    for (int i=0;i<n;i++){
        double s[NB]={0,0,0,0,0,0};
        for (int r=n+inc_start[i]; r<n+inc_start[i+1]; r++){
            for(int c=0;c<NB;c++){ s[c]+=buf[NB*(size_t)r+c]; buf[NB*(size_t)r+c]=0.0; }
        }
        for(int c=0;c<NB;c++){ s[c]+=buf[NB*(size_t)i+c]; buf[NB*(size_t)i+c]=0.0; }
        q_bn[i]+=s[4]; q_bs[i]+=s[5]; q_f[i]+=s[3];
        double mi=m[i], etai=eta[i], qv=0, we=0; double g[3]={g0,g1,g2};
        for(int d=0;d<3;d++){
            size_t q=3*(size_t)i+d; double fc=s[d];
            if (fr[q]!=0.0){
                double f=fc+mi*g[d]+fload[q];
                double vn=(v[q]+0.5*dt*a[q]+0.5*dt*f/mi)/(1.0+0.5*dt*etai/mi);
                a[q]=(f-etai*vn)/mi; v[q]=vn; qv+=0.5*etai*vn*dx[q];
            } else { a[q]=fc/mi; we-=0.5*fc*dx[q]; }
        }
        q_visc[i]+=qv; w_ext[i]+=we;
    }
}

void steps(int nsteps, int64_t code_t0, int64_t code_s0, int n, int W, double*x, double*v, double*a,
    double*dx, const double*fr, const double*fload, const double*props, const double*m,
    const double*eta, const NBR_T*nbr, const int32_t*ostart, const int8_t*mirror, CS_T*cstate,
    double*fs, const float*brate, double*buf, const int32_t*cstart, const int32_t*spill,
    const int32_t*inc_start, int nslab, double*q_visc, double*q_bn, double*q_bs, double*q_f,
    double*w_ext, double g0, double g1, double g2, double dt, int hertz, int ahead){
    #pragma omp parallel
    for (int k=0;k<nsteps;k++){
        move(n,x,v,a,dx,fr,fload,m,eta,q_visc,w_ext,dt);
        owner(n,W,nslab,x,dx,props,nbr,ostart,mirror,cstate,fs,brate,buf,cstart,spill,
              (CS_T)(code_t0+2*k),(CS_T)(code_s0+2*k),hertz,ahead);
        finish(n,v,a,dx,fr,fload,m,eta,buf,inc_start,q_visc,q_bn,q_bs,q_f,w_ext,g0,g1,g2,dt);
    }
}
